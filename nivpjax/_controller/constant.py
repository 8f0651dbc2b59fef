"""Fixed-step integration."""

import jax.numpy as jnp

from .._results import RESULTS
from .base import AbstractController, StepInfo


class ConstantStepSize(AbstractController):
    """Accept every step whose nonlinear solve succeeded, keep the step size `h0` (the last
    step is shortened to land on `t1`). A failed nonlinear solve halves the step (and the
    loop reports failure once it falls below `h_min`)."""

    h_min: float | None = None

    @property
    def needs_error_estimate(self) -> bool:
        return False

    @property
    def requires_h0(self) -> bool:
        return True

    @property
    def bounds(self):
        return self.h_min, None

    def init(self, t0, t1, y0, h0, f0, error_order, error_mask):
        if h0 is None:
            raise ValueError("A constant step size needs `h0`.")
        h = jnp.asarray(h0, y0.dtype)
        return h, h

    def adapt(self, info: StepInfo, state):
        ok = info.stats.nonlinear_result == RESULTS.successful
        ok = ok & jnp.all(jnp.isfinite(info.y1))
        h_next = jnp.where(ok, state, 0.5 * info.h)
        return ok, h_next, state
