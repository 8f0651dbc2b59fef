"""A learned step-size controller: an equinox module proposes the step factor inside the
compiled loop."""

import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._norms import scaled_rms_norm, violation_scale
from .._results import RESULTS
from .base import AbstractController, StepInfo, check_step_factors
from .events import event_margin, land_before_event
from .features import AbstractFeatures, FeatureMemory, StepFeatures
from .pid import PIDController


class PolicyState(eqx.Module):
    """The state of a [`nivpjax.PolicyController`][] between attempts.

    - `memory`: what the features remember ([`nivpjax.FeatureMemory`][]).
    - `grow`: whether the next step may grow (the last attempt was accepted and the one
      before it too).
    - `ok`: whether the last nonlinear solve succeeded.
    - `features`: the features of the last attempt (the observation of `nivpjax.rl`).
    """

    memory: FeatureMemory
    grow: Bool[Array, ""]
    ok: Bool[Array, ""]
    features: Float[Array, " f"]


class PolicyController(AbstractController):
    r"""Step sizes from a policy: after each attempt an equinox module maps the features of
    the attempt ([`nivpjax.StepFeatures`][] by default) to the log of the step factor,
    $h_{\text{next}} = h \exp(\text{action\_scale}\cdot\text{policy}(\phi)_0)$.

    Acceptance stays with the error test on the same estimate as
    [`nivpjax.PIDController`][]: a step is accepted when its scaled error norm (the
    violation counted as error) is at most 1 and its nonlinear solve succeeded. A bad policy
    therefore costs work, never accuracy. The factor is kept inside
    $[\text{factormin}, \text{factormax}]$, does not grow on a rejection nor right after one,
    and is `nonlinear_factor` after a failed nonlinear solve (safety rails, as for PID).

    **Arguments:**

    - `policy`: a callable module `features -> array`; entry 0 is the (unscaled) log
      factor. With `policy_accepts=True` entry 1 is an acceptance logit.
    - `features`: an [`nivpjax.AbstractFeatures`][]; default `StepFeatures(rtol, atol)`.
    - `rtol`, `atol`, `h_min`, `h_max`, `error_mask`, `nonlinear_factor`, `factormin`,
      `factormax`: as for [`nivpjax.PIDController`][] (the first step uses its estimate).
    - `action_scale`: multiplies the policy's output (e.g. $\log 10$ for a policy trained in
      `nivpjax.rl` with actions in $[-1, 1]$).
    - `policy_accepts`: off by default. When on, the policy decides acceptance
      (`policy(φ)[1] > 0`; failed nonlinear solves are still rejected): the error test
      no longer guards accuracy, so the result may be less accurate than `rtol` says.
    - `event_prediction`, `event_margin`: land steps just short of the event the projector
      predicts, after the policy's factor, as [`nivpjax.PIDController`][] does (a safety
      rail: the policy also sees the prediction among its features).
    - `differentiable_factor`: off by default, and then the factor is wrapped in
      `stop_gradient`, as in PID (gradients of a solve with respect to its parameters are
      those of the accepted mesh). On, reverse mode also flows through the factor into the
      policy's parameters (pathwise gradients; the accepted mesh is still piecewise
      constant in the parameters, so these gradients miss the cost of steps; the
      estimators of `nivpjax.learn` do not need them).
    """

    policy: Callable[..., Array]
    features: AbstractFeatures | None = None
    rtol: float = 1e-3
    atol: float = 1e-6
    h_min: float | None = None
    h_max: float | None = None
    error_mask: jax.Array | None = None
    nonlinear_factor: float = 0.25
    factormin: float = 0.2
    factormax: float = 10.0
    action_scale: float = 1.0
    policy_accepts: bool = eqx.field(static=True, default=False)
    differentiable_factor: bool = eqx.field(static=True, default=False)
    event_prediction: bool = eqx.field(static=True, default=True)
    event_margin: float | None = 1e-8

    def __check_init__(self):
        if not callable(self.policy):
            raise TypeError(f"`policy` must be a callable module, got {self.policy!r}.")
        if self.features is not None and not isinstance(self.features, AbstractFeatures):
            raise TypeError(f"`features` must be an AbstractFeatures, got {self.features!r}.")
        for name in ("rtol", "atol", "action_scale"):
            value = getattr(self, name)
            if isinstance(value, jax.core.Tracer):
                continue
            if isinstance(value, (str, bytes, bool)) or not np.issubdtype(
                np.asarray(value).dtype, np.number
            ):
                raise TypeError(f"`{name}` must be a real number, got {value!r}.")
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"`{name}` must be positive and finite, got {value}.")
        check_step_factors(self)

    @property
    def feature_map(self) -> AbstractFeatures:
        """The features in use (the default filled in with this controller's tolerances)."""
        if self.features is None:
            return StepFeatures(rtol=self.rtol, atol=self.atol)
        return self.features

    def tolerances(self):
        # The error test's tolerances (and the features'): stage solves held below them,
        # a contact's penetration charged like an error in its gap, as under PID.
        return self.rtol, self.atol

    @property
    def needs_error_estimate(self) -> bool:
        return True

    @property
    def bounds(self):
        return self.h_min, self.h_max

    def _pid(self):
        return PIDController(rtol=self.rtol, atol=self.atol, h_min=self.h_min, h_max=self.h_max)

    def init(self, t0, t1, y0, h0, f0, error_order, error_mask):
        h, _ = self._pid().init(t0, t1, y0, h0, f0, error_order, error_mask)
        features = self.feature_map
        state = PolicyState(
            memory=features.init(t0, t1, y0.dtype),
            grow=jnp.ones((), bool),
            ok=jnp.ones((), bool),
            features=jnp.zeros((features.size,), y0.dtype),
        )
        return h, state

    def error(self, info: StepInfo):
        """The scaled error norm of the error test (the violation counted as error), and
        whether the attempt is usable (nonlinear solve succeeded, everything finite)."""
        err = scaled_rms_norm(info.y_error, info.y0, info.y1, self.rtol, self.atol, info.error_mask)
        scale = violation_scale(self.rtol, self.atol, info.y0, info.error_mask)
        err = jnp.maximum(err, info.violation / scale)
        ok = info.stats.nonlinear_result == RESULTS.successful
        ok = ok & jnp.all(jnp.isfinite(info.y1)) & jnp.isfinite(err)
        return jnp.where(ok, err, jnp.inf), ok

    def step_factor(self, log_factor, state: PolicyState):
        """The factor applied to the last attempted step, from an (unscaled) log factor and
        the state after that attempt: clipped, no growth after a rejection,
        `nonlinear_factor` after a failed solve."""
        log_factor = jnp.clip(
            self.action_scale * log_factor, math.log(self.factormin), math.log(self.factormax)
        )
        factor = jnp.exp(log_factor)
        factor = jnp.where(state.grow, factor, jnp.minimum(factor, 1.0))
        factor = jnp.where(state.ok, factor, self.nonlinear_factor)
        if not self.differentiable_factor:
            factor = jax.lax.stop_gradient(factor)
        return factor

    def observe(self, info: StepInfo, state: PolicyState):
        """The error test and the features of an attempt: `(accept_by_error, err, state)`
        with the new state's `features` set (the policy is not evaluated)."""
        err, ok = self.error(info)
        features = self.feature_map
        phi = features(info, err, state.memory)
        accept = ok & (err <= 1)
        return accept, err, phi, ok

    def _remember(self, state: PolicyState, err, accept, ok, phi):
        features = self.feature_map
        rejected_before = state.memory.accepted < 0.5
        return PolicyState(
            memory=features.update(state.memory, err, accept),
            grow=accept & ~rejected_before,
            ok=ok,
            features=phi,
        )

    def adapt(self, info: StepInfo, state: PolicyState):
        accept, err, phi, ok = self.observe(info, state)
        out = jnp.atleast_1d(jnp.asarray(self.policy(phi))).astype(info.y1.dtype)
        if self.policy_accepts:
            accept = ok & (out[1] > 0)
        new_state = self._remember(state, err, accept, ok, phi)
        h_next = info.h * self.step_factor(out[0], new_state)
        if self.event_prediction:
            margin = event_margin(self.event_margin, self.rtol)
            h_next = land_before_event(info, accept, ok, h_next, margin)
        if self.h_max is not None:
            h_next = jnp.minimum(h_next, self.h_max)
        if not self.differentiable_factor:
            new_state = jax.lax.stop_gradient(new_state)
        return accept, h_next, new_state


class IntegralPolicy(eqx.Module):
    r"""The classical (integral) controller as a policy: log factor
    $\log(\text{safety}) - \phi_0 / k$, with $\phi_0 = \log e_n$ (feature 0 of
    [`nivpjax.StepFeatures`][]) and $k$ the error order. Under [`nivpjax.PolicyController`][]
    it reproduces [`nivpjax.PIDController`][] with its defaults; a baseline and a starting
    point for training."""

    order: int = eqx.field(static=True)
    safety: float = 0.9

    def __call__(self, features):
        return jnp.stack([jnp.log(self.safety) - features[0] / self.order])
