"""A small dense linear complementarity solver with an implicit-function JVP."""

import jax
import jax.numpy as jnp
from jax import lax

from .. import _linalg


def _active_solve(D, rhs, S):
    # Solve D_SS x_S = rhs_S, x = 0 off S, as one dense system of the full size.
    m = D.shape[0]
    both = S[:, None] & S[None, :]
    M = jnp.where(both, D, jnp.eye(m, dtype=D.dtype))
    return _linalg.solve_or_nan(M, jnp.where(S, rhs, 0.0))


def _lcp_residual(D, q, p):
    return jnp.max(jnp.abs(jnp.minimum(p, D @ p + q)), initial=0.0)


@jax.custom_jvp
def lcp_solve(D, q):
    r"""Solve the linear complementarity problem $0 \le p \perp Dp + q \ge 0$.

    Meant for the small systems of one contact step (a few to a few dozen contacts) with a
    P-matrix $D$ (a Delassus matrix of independent contacts). Method: a primal-dual active-set
    (semismooth Newton on $\min(p, Dp + q) = 0$) iteration, exact after finitely many steps
    for such matrices, at most $2m + 5$ iterations, followed by projected Gauss–Seidel sweeps
    that only matter for degenerate (redundant-contact) problems where the active-set iteration
    can cycle.

    JVP: the implicit function theorem on the active set $S = \{p_i > 0\}$,
    $D_{SS}\,dp_S = -(dD\,p + dq)_S$ and $dp = 0$ off $S$. A degenerate contact with $p_i = 0$
    and $(Dp + q)_i = 0$ is treated as inactive: it is on the boundary of the feasible set, and
    points of the set get the identity (no impulse reacts to a perturbation).
    """
    m = q.shape[0]
    diag = jnp.diagonal(D)
    p0 = jnp.maximum(0.0, -q / jnp.where(diag > 0, diag, 1.0))
    if m == 1:
        # One contact: p = max(0, -q/D) is the exact solution (D > 0); the iterations
        # below would only confirm it (and, under vmap, run their fallback regardless).
        return p0

    def cond(carry):
        k, _, changed = carry
        return (k < 2 * m + 5) & changed

    def body(carry):
        k, p, _ = carry
        S = p - (D @ p + q) > 0
        p_new = _active_solve(D, -q, S)
        p_new = jnp.where(jnp.isfinite(p_new), p_new, p)
        changed = jnp.any(jnp.abs(p_new - p) > 0)
        return k + 1, p_new, changed

    _, p, _ = lax.while_loop(cond, body, (jnp.array(0), p0, jnp.array(True)))
    p = jnp.maximum(p, 0.0)

    def pgs_sweep(p):
        def one(i, p):
            w_i = D[i] @ p + q[i]
            d_i = jnp.where(diag[i] > 0, diag[i], 1.0)
            return p.at[i].set(jnp.maximum(0.0, p[i] - w_i / d_i))

        return lax.fori_loop(0, m, one, p)

    # Projected Gauss-Seidel only while the active-set result is not exact (degenerate
    # problems). A while loop rather than `lax.cond`: under vmap a cond runs both branches,
    # i.e. all 50 m sweeps for every member; the loop stops once no member needs a sweep.
    scale = 1.0 + jnp.max(jnp.abs(q), initial=0.0)
    tol = 1e3 * jnp.finfo(q.dtype).eps * scale

    def pgs_cond(carry):
        k, p = carry
        return (k < 50 * m) & (_lcp_residual(D, q, p) > tol)

    def pgs_body(carry):
        k, p = carry
        return k + 1, pgs_sweep(p)

    _, p = lax.while_loop(pgs_cond, pgs_body, (jnp.array(0), p))
    return p


@lcp_solve.defjvp
def _lcp_solve_jvp(primals, tangents):
    D, q = primals
    dD, dq = tangents
    p = lcp_solve(D, q)
    S = p > 0
    dp = _active_solve(D, -(dD @ p + dq), S)
    return p, dp
