"""Euclidean ball of a (possibly state-dependent) radius: 2-D Coulomb friction."""

import jax
import jax.numpy as jnp

from .base import AbstractProjector, Bound, ProjectionContext, resolve


def _safe_norm(w):
    sq = jnp.sum(w**2)
    positive = sq > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0)


@jax.custom_jvp
def project_ball(w, radius):
    r"""Project the vector `w` onto $\{v : |v| \le r\}$ with $r = \max(\text{radius}, 0)$.

    Jacobian: identity where $|w| \le r$ and $r > 0$ (the point is in the set; the boundary
    $|w| = r$ included); $\frac{r}{|w|}(I - \hat w \hat w^T)\,dw + \hat w\,dr$ outside; zero
    when $r \le 0$ (the set is the single point 0).
    """
    r = jnp.maximum(radius, 0.0)
    nrm = _safe_norm(w)
    inside = (nrm <= r) & (r > 0)
    scale = jnp.where(inside, 1.0, r / jnp.where(nrm > 0, nrm, 1.0))
    return jnp.where(r > 0, scale, 0.0) * w


@project_ball.defjvp
def _project_ball_jvp(primals, tangents):
    w, radius = primals
    dw, dradius = tangents
    out = project_ball(w, radius)
    r = jnp.maximum(radius, 0.0)
    nrm = _safe_norm(w)
    inside = (nrm <= r) & (r > 0)
    nrm_safe = jnp.where(nrm > 0, nrm, 1.0)
    what = w / nrm_safe
    d_out = (r / nrm_safe) * (dw - what * jnp.dot(what, dw)) + what * dradius
    d_out = jnp.where(inside, dw, jnp.where(r > 0, d_out, jnp.zeros_like(dw)))
    return out, d_out.astype(out.dtype)


class Ball(AbstractProjector):
    r"""Projection of the whole (sub)vector onto the Euclidean ball of radius $r$.

    Used for 2-D Coulomb friction, $\lambda_T \in \{|\lambda_T| \le \mu N\}$, where the radius is
    a callable `radius(t, y, args)` of the current iterate. See [`nivpjax.project_ball`][]
    for the Jacobian at the kinks (identity on the closed ball; zero for a radius $\le 0$).

    float32: the normalisation $w / |w|$ loses relative accuracy only for $|w|$ near the
    underflow threshold.
    """

    radius: Bound

    def __call__(self, z, ctx: ProjectionContext):
        z = jnp.asarray(z)
        return project_ball(z, resolve(self.radius, ctx, z.dtype))
