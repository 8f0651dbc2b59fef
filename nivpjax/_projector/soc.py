r"""The $\mu$-scaled second-order (friction) cone $K_\mu = \{(s, w) : |w| \le \mu s\}$."""

import jax
import jax.numpy as jnp

from .base import AbstractProjector, Bound, ProjectionContext, resolve


def _norm(w):
    # Guarded so that the unselected branches stay finite in reverse mode at w = 0.
    sq = jnp.sum(w**2)
    return jnp.where(sq > 0, jnp.sqrt(jnp.where(sq > 0, sq, 1.0)), 0.0)


def _regions(s, w, mu):
    r = _norm(w)
    inside = (r <= mu * s) & (s >= 0)
    polar = (mu * r <= -s) & ~inside
    return r, inside, polar


def _boundary_piece(s, w, mu):
    # The projection onto the boundary ray through w; smooth where r > 0 (the piece is never
    # selected at r = 0).
    r = _norm(w)
    r_safe = jnp.where(r > 0, r, 1.0)
    alpha = (s + mu * r) / (1.0 + mu**2)
    return alpha, (mu * alpha / r_safe) * w


@jax.custom_jvp
def project_soc(s, w, mu):
    r"""Project $(s, w)$, $s$ scalar and $w \in \mathbb{R}^k$, onto
    $K_\mu = \{(s, w) : |w| \le \mu s,\ s \ge 0\}$, $\mu \ge 0$ (the condition $s \ge 0$
    only matters at $\mu = 0$, where it makes $K_0 = \{w = 0, s \ge 0\}$ the limit of the
    cones as $\mu \to 0^+$).

    Three regions: inside $K_\mu$ the point is returned; in the polar cone
    $\{\mu |w| \le -s\}$ the result is 0; otherwise it is the projection onto the boundary ray,
    $\alpha (1, \mu \hat w)$ with $\alpha = (s + \mu |w|) / (1 + \mu^2)$.

    Jacobian at kinks: identity on the closed cone (including the apex), zero on the closed
    polar cone (minus the apex), the boundary piece's derivative elsewhere. Derivatives with
    respect to a state-dependent $\mu$ are included.
    """
    r, inside, polar = _regions(s, w, mu)
    alpha, w_b = _boundary_piece(s, w, mu)
    s_out = jnp.where(inside, s, jnp.where(polar, 0.0, alpha))
    w_out = jnp.where(inside, w, jnp.where(polar, 0.0, w_b))
    return s_out, w_out


@project_soc.defjvp
def _project_soc_jvp(primals, tangents):
    s, w, mu = primals
    r, inside, polar = _regions(s, w, mu)
    (alpha, w_b), (dalpha, dw_b) = jax.jvp(_boundary_piece, primals, tangents)
    ds, dw, _ = tangents
    s_out = jnp.where(inside, s, jnp.where(polar, 0.0, alpha))
    w_out = jnp.where(inside, w, jnp.where(polar, 0.0, w_b))
    ds_out = jnp.where(inside, ds, jnp.where(polar, 0.0, dalpha))
    dw_out = jnp.where(inside, dw, jnp.where(polar, 0.0, dw_b))
    return (s_out, w_out), (ds_out.astype(s_out.dtype), dw_out.astype(w_out.dtype))


class SecondOrderCone(AbstractProjector):
    r"""Projection of a vector $(s, w_1, \dots, w_k)$ onto the friction cone
    $K_\mu = \{|w| \le \mu s\}$: 3-D frictional contact with normal component $s$ and
    tangential components $w$ (or, with $k = 1$, planar friction).

    `mu` is a scalar array or a callable `mu(t, y, args)` (state-dependent friction). Kinks:
    see [`nivpjax.project_soc`][].

    float32: the boundary piece divides by $|w|$; results are accurate to a few ulps of
    $\max(|s|, |w|)$.
    """

    mu: Bound

    def __call__(self, z, ctx: ProjectionContext):
        z = jnp.asarray(z)
        mu = resolve(self.mu, ctx, z.dtype)
        s_out, w_out = project_soc(z[0], z[1:], mu)
        return jnp.concatenate([s_out[None], w_out])
