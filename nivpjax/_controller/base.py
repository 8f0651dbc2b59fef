"""The step-size controller interface."""

import abc
from typing import Any

import equinox as eqx
from jaxtyping import Array, Bool, Float

from .._solution import StepStats


class StepInfo(eqx.Module):
    """Everything a controller may look at after an attempted step, as one object (a learned
    controller computes its features from it without a new signature).

    - `t0`, `h`: where the attempt started and its size.
    - `t1`: the end of the integration interval.
    - `y0`, `y1`: the state before and the candidate after the step.
    - `y_error`: the local error estimate (zeros if the stepper has none).
    - `error_order`: the power of $h$ in `y_error`.
    - `stats`: nonlinear diagnostics ([`nivpjax.StepStats`][]).
    - `error_mask`: components that enter the error norm (differential rows by default).
    - `violation`: constraint violation at `y1` of constraints inactive at `y0` (e.g. a
      contact crossed inside the step), in state units; adaptive controllers count it as
      error so that such events get located.
    - `next_event`: the predicted time from `t0` to the first nonsmooth event (a contact
      closing, a switching function crossing zero) that the projector foresees from the
      data at both ends of the attempt, inside the attempt or beyond it; `inf` when none
      is predicted (see [`nivpjax.AbstractProjector.next_event`][]).
    - `event_after_end`: the same, of the first event after the attempt's end (what sizes
      the next step if this one is accepted): events inside the attempt, which it
      crossed, and at its end, which the next step starts on, are left out
      (`ProjectionContext.after_end`); equal to `next_event` where the projector makes
      no such difference.
    """

    t0: Float[Array, ""]
    h: Float[Array, ""]
    t1: Float[Array, ""]
    y0: Float[Array, " n"]
    y1: Float[Array, " n"]
    y_error: Float[Array, " n"]
    error_order: int = eqx.field(static=True)
    stats: StepStats
    error_mask: Bool[Array, " n"]
    violation: Float[Array, ""]
    next_event: Float[Array, ""]
    event_after_end: Float[Array, ""] | None = None

    @property
    def next_event_after_end(self):
        """`event_after_end`, or `next_event` where it is not given."""
        return self.next_event if self.event_after_end is None else self.event_after_end


class AbstractController(eqx.Module):
    """Decides whether to accept a step and how large the next one is.

    - `init(t0, t1, y0, h0, f0, error_order, error_mask) -> (h, state)`: the first step size
      (`h0` if given, otherwise the controller's own estimate; `f0` is the rate $y'(t_0)$
      at the consistent initial state: $A^{-1} f$ on differential rows, zero on algebraic
      rows) and the controller's state.
    - `adapt(info, state) -> (accept, h_next, state)`: after an attempt. Failed nonlinear
      solves arrive with `info.stats.nonlinear_result` set; a controller must reject them.
    - `h_min`, `h_max`: step bounds enforced by the loop (`h_min` failures set
      `RESULTS.h_min_reached`).
    - `needs_error_estimate`: if True the solver gives the stepper an error estimate
      (embedded or Richardson).
    """

    @property
    @abc.abstractmethod
    def needs_error_estimate(self) -> bool: ...

    @property
    def step_doubling(self) -> bool:
        """Whether the controller needs a step-doubling estimate (the stepper wrapped in
        [`nivpjax.Richardson`][]) even where the stepper embeds one."""
        return False

    def tolerances(self):
        """`(rtol, atol)` that each step's error is held to, or `None` where the controller
        does not hold steps to a tolerance. A stage's nonlinear solve is then held at
        least `STAGE_FRACTION` times tighter (see
        [`nivpjax.AbstractNonlinearSolver`][])."""
        return None

    @property
    def requires_h0(self) -> bool:
        """Whether `solve` must be given `h0` (no step-size estimate of its own)."""
        return False

    @property
    @abc.abstractmethod
    def bounds(self) -> tuple[Any, Any]:
        """`(h_min, h_max)`, each a float or `None`."""

    @abc.abstractmethod
    def init(self, t0, t1, y0, h0, f0, error_order, error_mask): ...

    @abc.abstractmethod
    def adapt(self, info: StepInfo, state): ...


def check_step_factors(controller) -> None:
    """The step-factor options shared by the controllers: `factormin` in (0, 1],
    `factormax` >= 1, `nonlinear_factor` in (0, 1)."""
    if not 0 < controller.factormin <= 1:
        raise ValueError(
            f"`factormin` must satisfy 0 < factormin <= 1, got {controller.factormin}."
        )
    if not controller.factormax >= 1:
        raise ValueError(f"`factormax` must be >= 1, got {controller.factormax}.")
    if not 0 < controller.nonlinear_factor < 1:
        raise ValueError(
            f"`nonlinear_factor` must lie in (0, 1), got {controller.nonlinear_factor}."
        )
