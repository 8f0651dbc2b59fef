"""Box, half-line and interval projections: the clip kernel and its selected Jacobian."""

import jax
import jax.numpy as jnp

from .base import AbstractProjector, Bound, ProjectionContext, face, resolve


@jax.custom_jvp
def clip(z, lower, upper):
    r"""$\min(\max(z, \ell), u)$ with a chosen element of the generalised Jacobian.

    Derivative: $\partial/\partial z = 1$ on $\ell \le z \le u$ (boundary included: the point
    lies in the set, so it gets the identity), $\partial/\partial \ell = 1$ where $z < \ell$ and
    $\partial/\partial u = 1$ where $z > u$. Plain `jnp.clip` returns 1/2 at the kinks, which
    is no element of the B-subdifferential; never rely on it.
    """
    return jnp.minimum(jnp.maximum(z, lower), upper)


@clip.defjvp
def _clip_jvp(primals, tangents):
    z, lower, upper = primals
    dz, dlower, dupper = tangents
    out = clip(z, lower, upper)
    below = z < lower
    above = z > upper
    dout = jnp.where(below, dlower, jnp.where(above, dupper, dz))
    return out, jnp.broadcast_to(dout, out.shape).astype(out.dtype)


class Box(AbstractProjector):
    r"""Projection onto the box $[\ell, u]$ (componentwise clip).

    Covers saturation, the interval $[-1, 1]$ of a relay/sign multiplier, and 1-D Coulomb
    friction $[-\mu N, \mu N]$. Each bound is an array (broadcast against `z`) or a callable
    `bound(t, y, args)` evaluated at the current iterate, so state-dependent bounds such as
    a slip-weakening $\mu(|u|) N$ get their chain rule from autodiff.

    Kinks: identity on the closed box (see [`nivpjax.AbstractProjector`][]), derivative with
    respect to the violated bound outside. `lower > upper` is the user's error and is not
    checked inside compiled code.

    float32: no caveats (a clip is exact).
    """

    lower: Bound
    upper: Bound

    def __call__(self, z, ctx: ProjectionContext):
        z = jnp.asarray(z)
        lower = resolve(self.lower, ctx, z.dtype)
        upper = resolve(self.upper, ctx, z.dtype)
        return clip(z, lower, upper)

    def switched(self, ctx: ProjectionContext):
        """A component moved onto, off or between the bounds."""
        dtype = ctx.y_iter.dtype
        lower = resolve(self.lower, ctx, dtype)
        upper = resolve(self.upper, ctx, dtype)
        z0, z1 = ctx.restrict(ctx.y_prev), ctx.restrict(ctx.y_iter)
        return jnp.any(face(z0, lower, upper) != face(z1, lower, upper))


class NonNegative(AbstractProjector):
    r"""Projection onto the non-negative orthant, $\max(z, 0)$: unilateral constraints,
    ideal diodes, complementarity multipliers. At $z = 0$ the Jacobian is the identity
    (the point is feasible)."""

    def __call__(self, z, ctx: ProjectionContext):
        z = jnp.asarray(z)
        return clip(z, jnp.zeros((), z.dtype), jnp.asarray(jnp.inf, z.dtype))

    def switched(self, ctx: ProjectionContext):
        """A component became zero or positive."""
        z0, z1 = ctx.restrict(ctx.y_prev), ctx.restrict(ctx.y_iter)
        return jnp.any((z0 <= 0) != (z1 <= 0))


def sign_resolvent_interval(z, tau_s):
    """`clip(z + tau_s, -1, 1)`: the resolvent of the sign relation (see `SignResolvent`)."""
    one = jnp.ones((), z.dtype)
    return clip(z + tau_s, -one, one)
