"""Event location on a switching surface for any projector."""

from collections.abc import Callable
from typing import Any

import jax.numpy as jnp

from .base import AbstractProjector, ProjectionContext


class EventLocated(AbstractProjector):
    r"""`projector` unchanged, plus event location on a switching surface $s(t, y) = 0$.

    When a component of $s$ changes sign between the two ends of a step, the switch
    happened inside it and the scheme integrated part of the step with the wrong branch: a
    local error of order $h$ times the jump of the vector field that Richardson
    extrapolation or an embedded pair cannot see (both ends lie on the same branches). The
    `violation` is then $\min(|s_0|, |s_1|)$, which adaptive controllers count as error, so
    the step shrinks until the switch lies within tolerance of a step boundary.

    Used by the relay, diode and saturation effects of scenes; wrap your own projectors the
    same way. `surface(t, y, args)` receives the full state.
    """

    projector: AbstractProjector
    surface: Callable[[Any, Any, Any], Any]

    def validate(self, n: int) -> None:
        self.projector.validate(n)

    def __call__(self, z, ctx: ProjectionContext):
        return self.projector(z, ctx)

    def initial_violation(self, ctx: ProjectionContext):
        return self.projector.initial_violation(ctx)

    def impulsive(self, ctx: ProjectionContext):
        return self.projector.impulsive(ctx)

    @property
    def has_event_time(self) -> bool:
        return self.projector.has_event_time

    def event_time(self, ctx: ProjectionContext):
        return self.projector.event_time(ctx)

    def violation(self, ctx: ProjectionContext):
        s0 = jnp.atleast_1d(self.surface(ctx.t - ctx.h, ctx.y_prev, ctx.args))
        s1 = jnp.atleast_1d(self.surface(ctx.t, ctx.y_iter, ctx.args))
        crossed = s0 * s1 < 0
        size = jnp.minimum(jnp.abs(s0), jnp.abs(s1))
        own = jnp.max(jnp.where(crossed, size, 0.0), initial=0.0).astype(ctx.y_iter.dtype)
        return jnp.maximum(own, self.projector.violation(ctx))
