"""Landing steps just before predicted events, shared by the controllers."""

import jax
import jax.numpy as jnp

from .base import StepInfo


EVENT_SKIP = 1e-2

# The margin short of a predicted event that follows the tolerance (`event_margin=None`,
# opt-in): `MARGIN_PER_RTOL * rtol`, at most `MARGIN_MAX` (so 1e-8 for rtol >= 1e-6).
# Below that, a step lands closer to the event: the impact applied early by that fraction
# of a step, and a landing that the prediction's own error carries across the contact is
# rejected and retried by the violation test, both fall with the tolerance. The default
# fixed 1e-8 holds a bouncing ball's error at 1.1e-7 for every rtol from 1e-3 to 1e-10;
# this one gives 8e-10 at rtol 1e-8 and 3e-12 at 1e-10 (`tests/test_event_margin.py`).
# Smaller margins at rtol 1e-6 (1e-9) bought rejections and no accuracy: 49 rejections for
# 132 steps on the Zeno ball against 0 for 88 (`tests/test_event_prediction.py`). Not the
# default: a spring slider's derivative through its friction reversals came out 14% off
# at rtol 1e-8 with it (`test_slider_reversals_converge_to_exact_derivative`): a step that
# landed within round-off of a reversal lost its term. Fixed since (`CoulombFriction.
# switch_shift`, `tests/test_reversal_gradients.py`): with `None` that derivative is
# 5.8e-4 .. 2.7e-7 off at rtol 1e-5 .. 1e-10 (Bathe), at least as close as with 1e-8.
MARGIN_MAX = 1e-8
MARGIN_PER_RTOL = 1e-2


def event_margin(margin, rtol):
    """The relative margin short of a predicted event: `margin` when given (the
    controllers' default is 1e-8), `min(MARGIN_MAX, MARGIN_PER_RTOL * rtol)` for `None`
    (`rtol` may be a run-time value)."""
    if margin is not None:
        return margin
    return jnp.minimum(MARGIN_MAX, MARGIN_PER_RTOL * jnp.asarray(rtol))


def land_before_event(info: StepInfo, accept, ok, h_next, margin):
    r"""Shorten the proposed step `h_next` so that it ends a relative `margin` short of the
    event the projector predicts (measured from `info.t0`).

    - After an acceptance the next step starts at `t0 + h`, and the first event after the
      attempt's end counts (`info.next_event_after_end`); after a rejection, at `t0`
      (`info.next_event`).
    - A step that would start within `EVENT_SKIP` of its size from the event steps over it:
      the event then sits at the start of the step, where the scheme resolves it.
    - A rejected attempt that crossed the event before its last `EVENT_SKIP` is retried up
      to just before it (the error-controlled factor judged the whole attempt, including
      the crossing); one that crossed it later is left to the error-controlled factor.

    No prediction (`inf`) leaves `h_next` unchanged; the result carries no gradient."""
    to_event = jnp.where(accept, info.next_event_after_end - info.h, info.next_event)
    # In the step's dtype: a margin computed from a float64 rtol must not promote a
    # float32 solve's step size.
    land = jax.lax.stop_gradient((to_event * (1 - margin)).astype(to_event.dtype))
    coming = jnp.isfinite(to_event) & (to_event > EVENT_SKIP * h_next)
    # Retrying up to the event must shorten the attempt: an event in its last EVENT_SKIP
    # (an attempt that ends on the surface, up to the solver's tolerance on either side)
    # gave a retry 1 - margin times the attempt, rejected again for the same error: a
    # loop to max_steps (measured: a sliding-mode landing with the VI solver, 7936
    # rejections of h = 2.93e-3 at one time). The error-controlled factor decides then.
    crossed = ~accept & ok & (info.next_event < info.h * (1 - EVENT_SKIP))
    h_next = jnp.where(coming, jnp.minimum(h_next, land), h_next)
    return jnp.where(crossed & coming, jnp.minimum(land, info.h), h_next)
