"""Turn a user's own projection function (and optionally its Jacobian) into a projector."""

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp

from .base import AbstractProjector, ProjectionContext


class CustomProjector(AbstractProjector):
    r"""Wrap `project(z, ctx) -> array` as a projector.

    If `jacobian(z, ctx) -> (n, n)` is given it supplies the generalised Jacobian with
    respect to `z` through a `jax.custom_jvp` rule (use this when `project` has kinks: say
    which element you return); derivatives with respect to the context (state-dependent sets,
    parameters in `ctx.args`) still come from autodiff of `project`. Without `jacobian`, JAX
    differentiates `project` as written, which is fine for smooth code and for kernels that
    already carry their own custom JVPs (e.g. [`nivpjax.clip`][]).
    """

    project: Callable[[Any, ProjectionContext], Any]
    jacobian: Callable[[Any, ProjectionContext], Any] | None = None

    def __call__(self, z, ctx: ProjectionContext):
        z = jnp.asarray(z)
        if self.jacobian is None:
            return jnp.asarray(self.project(z, ctx), z.dtype)
        dynamic, static = eqx.partition(ctx, eqx.is_inexact_array)
        project, jacobian = self.project, self.jacobian

        @jax.custom_jvp
        def _p(z, dynamic):
            return jnp.asarray(project(z, eqx.combine(dynamic, static)), z.dtype)

        @_p.defjvp
        def _p_jvp(primals, tangents):
            z, dynamic = primals
            dz, ddynamic = tangents
            raw = lambda d: jnp.asarray(project(z, eqx.combine(d, static)), z.dtype)
            out, d_ctx = jax.jvp(raw, (dynamic,), (ddynamic,))
            J = jnp.asarray(jacobian(z, eqx.combine(dynamic, static)), z.dtype)
            return out, J @ dz + d_ctx

        return _p(z, dynamic)
