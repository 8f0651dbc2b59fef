"""A diffrax-style PID step-size controller with a masked error norm."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import FloatScalar, plain_int, runtime_float
from .._norms import scaled_rms_norm, violation_scale
from .._results import RESULTS
from .base import AbstractController, StepInfo, check_step_factors
from .events import event_margin, land_before_event


class PIDController(AbstractController):
    r"""Adaptive step size from the local error estimate, as in diffrax.

    With $e_n$ the RMS of the error scaled by $\text{atol} + \text{rtol}\max(|y_0|, |y_1|)$
    over the masked components and $k$ the error order, the step factor is

    $$ \text{safety}\cdot e_n^{-\beta_1/k} e_{n-1}^{-\beta_2/k} e_{n-2}^{-\beta_3/k},\quad
       \beta_1 = p + i + d,\ \beta_2 = -(p + 2d),\ \beta_3 = d, $$

    clipped to `[factormin, factormax]` (and to at most 1 on a rejection and on the step
    after one). A step is
    accepted when $e_n \le 1$. A constraint violated at the end of a step without having
    been enforced in it (`StepInfo.violation`, e.g. a missed contact) enters $e_n$ scaled
    by $\text{atol} + \text{rtol}\,\|y_0\|_\infty$, which locates impacts. A failed nonlinear
    solve is rejected and the step shrinks by `nonlinear_factor`. The factor is never
    differentiated (`stop_gradient`): differentiating $e^{-1/k}$ through an adaptive loop
    gives meaningless, enormous gradients.

    **Arguments:**

    - `rtol`, `atol`: tolerances (positive).  Stored as (weakly typed) JAX scalars, like
      `h_min` and `h_max`: they are run-time values of the compiled solve, so a sweep over
      tolerances or step bounds compiles once. Only whether `h_min`/`h_max` is `None` is
      part of the compiled structure.
    - `pcoeff`, `icoeff`, `dcoeff`: PID coefficients (default: integral only, i.e. the
      classical controller).
    - `safety`, `factormin`, `factormax`: factor safety and clipping.
    - `h_min`, `h_max`: step bounds (`None`: no upper bound, and a lower bound of a few
      hundred ulps of `t1`).
    - `error_mask`: boolean array selecting the components in the norm; `None` uses the
      differential rows of the mass matrix.
    - `nonlinear_factor`: shrink factor after a failed nonlinear solve.
    - `error_order`: overrides the stepper's error order $k$ in the exponents (`None`: use
      the stepper's).
    - `event_prediction`: land steps just before the next nonsmooth event that the
      projector predicts (`StepInfo.next_event`: a contact closing, a switching function
      reaching zero), so events are met at step boundaries instead of being located by
      rejections. After a rejection whose attempt crossed an event, the next attempt
      lands just before that event; after an acceptance the next step is shortened to
      the event when it comes before the error-controlled step. A step that already
      starts within 1% of its size from the event steps over it (the event then
      sits at the start of the step, where the scheme resolves it). Rejection by the
      error test stays the safety net.
    - `event_margin`: relative distance short of the predicted event to land at
      (default $10^{-8}$). `None` follows the tolerance, $\min(10^{-8}, 10^{-2}\,
      \text{rtol})$, so that the time an impact is applied early does not floor the
      error below rtol $10^{-6}$ (a bouncing ball: $1.1 \cdot 10^{-7}$ at every rtol
      with the default, $8 \cdot 10^{-10}$ at rtol $10^{-8}$). Not the default: with it a
      friction-reversal derivative at rtol $10^{-8}$ came out 14% off, a step landing
      within round-off of the reversal losing its term (fixed since:
      `tests/test_reversal_gradients.py`).
    """

    rtol: FloatScalar = eqx.field(default=1e-3, converter=runtime_float)
    atol: FloatScalar = eqx.field(default=1e-6, converter=runtime_float)
    pcoeff: float = 0.0
    icoeff: float = 1.0
    dcoeff: float = 0.0
    safety: float = 0.9
    factormin: float = 0.2
    factormax: float = 10.0
    h_min: FloatScalar | None = eqx.field(default=None, converter=runtime_float)
    h_max: FloatScalar | None = eqx.field(default=None, converter=runtime_float)
    error_mask: jax.Array | None = None
    nonlinear_factor: float = 0.25
    error_order: int | None = eqx.field(static=True, default=None, converter=plain_int)
    event_prediction: bool = eqx.field(static=True, default=True)
    event_margin: float | None = 1e-8

    def __check_init__(self):
        for name in ("rtol", "atol", "safety"):
            value = getattr(self, name)
            if isinstance(value, jax.core.Tracer):
                continue  # batched or differentiated tolerances: checked by the caller
            if isinstance(value, (str, bytes)) or not np.issubdtype(
                np.asarray(value).dtype, np.number
            ):
                raise TypeError(f"`{name}` must be a real number, got {value!r}.")
            value = np.asarray(value)  # checked on the host: no JAX dispatch per check
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"`{name}` must be positive and finite, got {value}.")
        for name in ("h_min", "h_max"):
            value = getattr(self, name)
            if value is None or isinstance(value, jax.core.Tracer):
                continue
            if isinstance(value, (str, bytes, bool)) or not np.issubdtype(
                np.asarray(value).dtype, np.number
            ):
                raise TypeError(f"`{name}` must be a real number, got {value!r}.")
            if not np.isfinite(value):
                raise ValueError(f"`{name}` must be finite, got {value}.")
        bounds = (self.h_min, self.h_max)
        concrete = not any(isinstance(b, jax.core.Tracer) or b is None for b in bounds)
        if concrete and np.asarray(self.h_min) > np.asarray(self.h_max):
            raise ValueError(
                f"`h_min` must not exceed `h_max`, got h_min={self.h_min}, h_max={self.h_max}."
            )
        check_step_factors(self)
        if self.error_order is not None and not (
            isinstance(self.error_order, int) and self.error_order >= 1
        ):
            raise ValueError(f"`error_order` must be an int >= 1, got {self.error_order!r}.")

    def tolerances(self):
        return self.rtol, self.atol

    @property
    def needs_error_estimate(self) -> bool:
        return True

    @property
    def bounds(self):
        return self.h_min, self.h_max

    def init(self, t0, t1, y0, h0, f0, error_order, error_mask):
        dtype = y0.dtype
        one = jnp.ones((), dtype)
        if h0 is not None:
            h = jnp.asarray(h0, dtype)
        else:
            # Hairer–Wanner's first guess: 1% of the ratio of the scaled state and slope.
            mask = error_mask
            d0 = scaled_rms_norm(y0, y0, y0, self.rtol, self.atol, mask)
            d1 = scaled_rms_norm(f0, y0, y0, self.rtol, self.atol, mask)
            small = (d0 < 1e-5) | (d1 < 1e-5)
            h = jnp.where(small, 1e-6, 0.01 * d0 / jnp.where(d1 > 0, d1, 1.0))
            h = jnp.minimum(h, 0.1 * jnp.abs(t1 - t0))
            h = jax.lax.stop_gradient(h.astype(dtype))
        if self.h_max is not None:
            h = jnp.minimum(h, self.h_max)
        if self.h_min is not None:
            h = jnp.maximum(h, self.h_min)
        return h, (one, one, jnp.zeros((), bool))

    def adapt(self, info: StepInfo, state):
        prev, prev_prev, rejected_before = state
        err = scaled_rms_norm(info.y_error, info.y0, info.y1, self.rtol, self.atol, info.error_mask)
        # A constraint crossed inside the step counts as error, scaled like the state.
        scale = violation_scale(self.rtol, self.atol, info.y0, info.error_mask)
        err = jnp.maximum(err, info.violation / scale)
        ok = info.stats.nonlinear_result == RESULTS.successful
        finite = jnp.all(jnp.isfinite(info.y1)) & jnp.isfinite(err)
        ok = ok & finite
        accept = ok & (err <= 1)
        k = info.error_order if self.error_order is None else self.error_order
        beta1 = (self.pcoeff + self.icoeff + self.dcoeff) / k
        beta2 = -(self.pcoeff + 2 * self.dcoeff) / k
        beta3 = self.dcoeff / k
        inv = 1.0 / jnp.maximum(jnp.where(ok, err, 1.0), 1e-10)
        factor = self.safety * inv**beta1 * prev**beta2 * prev_prev**beta3
        factor = jnp.clip(factor, self.factormin, self.factormax)
        # No growth on a rejection, nor on the step right after one (Hairer & Wanner): it
        # stops grow/reject cascades, e.g. while approaching an impact.
        factor = jnp.where(accept & ~rejected_before, factor, jnp.minimum(factor, 1.0))
        factor = jnp.where(ok, factor, self.nonlinear_factor)
        factor = jax.lax.stop_gradient(factor)
        h_next = info.h * factor
        if self.event_prediction:
            margin = event_margin(self.event_margin, self.rtol)
            h_next = land_before_event(info, accept, ok, h_next, margin)
        if self.h_max is not None:
            h_next = jnp.minimum(h_next, self.h_max)
        new_state = (jnp.where(accept, inv, prev), jnp.where(accept, prev, prev_prev), ~accept)
        return accept, h_next, jax.lax.stop_gradient(new_state)
