r"""Restarted GMRES that stops at the product which meets its tolerance.

lineax's GMRES fills its whole Krylov space before it tests the residual, and starts each
solve with a product for $b - A x_0$ even when $x_0 = 0$. An inexact Newton direction
needs only a loose relative residual (an Eisenstat-Walker forcing term), which one or two
products often meet: on the fault's stages a Newton iteration spent 7 products where 2 to 3
sufficed. This one is Saad & Schultz's (1986) GMRES(m) with Givens rotations, whose
recurrence gives $\|b - A x_j\|_2$ after every product at no cost, and stops there.

Orthogonalisation is classical Gram-Schmidt applied twice ("twice is enough", Giraud et
al. 2005): two matrix-vector products with the basis instead of $j$ dependent dot
products, as accurate as modified Gram-Schmidt.
"""

import jax.numpy as jnp
from jax import lax
from jax.scipy.linalg import solve_triangular


def _safe(x):
    return jnp.where(x > 0, x, 1.0)


def _rotate(column, cs, sn, j, restart):
    """Apply the first `j` Givens rotations to a new Hessenberg column."""

    def body(i, c):
        a, b = c[i], c[i + 1]
        rotated = c.at[i].set(cs[i] * a + sn[i] * b).at[i + 1].set(-sn[i] * a + cs[i] * b)
        return jnp.where(i < j, rotated, c)

    return lax.fori_loop(0, restart, body, column)


def _cycle(matvec, r, beta, tol, restart):
    """One cycle from the residual `r` (norm `beta`): `(dx, residual estimate, products)`."""
    n, dtype = r.shape[0], r.dtype
    V = jnp.zeros((restart + 1, n), dtype).at[0].set(r / _safe(beta))
    H = jnp.zeros((restart + 1, restart), dtype)
    rot = jnp.zeros((restart,), dtype)
    g = jnp.zeros((restart + 1,), dtype).at[0].set(beta)
    rows = jnp.arange(restart + 1)

    def cond(c):
        j, _, _, _, _, g = c
        return (j < restart) & (jnp.abs(g[j]) > tol)

    def body(c):
        j, V, H, cs, sn, g = c
        w = matvec(V[j])
        h = jnp.zeros((restart + 1,), dtype)
        for _ in range(2):  # classical Gram-Schmidt, twice
            step = jnp.where(rows <= j, V @ w, 0.0)
            w = w - step @ V
            h = h + step
        h_next = jnp.linalg.norm(w)
        V = V.at[j + 1].set(w / _safe(h_next))
        column = _rotate(h.at[j + 1].set(h_next), cs, sn, j, restart)
        a, b = column[j], column[j + 1]
        d = jnp.hypot(a, b)
        c_j, s_j = jnp.where(d > 0, a / _safe(d), 1.0), jnp.where(d > 0, b / _safe(d), 0.0)
        column = column.at[j].set(d).at[j + 1].set(0.0)
        H = H.at[:, j].set(column)
        g = g.at[j + 1].set(-s_j * g[j]).at[j].set(c_j * g[j])
        return j + 1, V, H, cs.at[j].set(c_j), sn.at[j].set(s_j), g

    m, V, H, _, _, g = lax.while_loop(cond, body, (0, V, H, rot, rot, g))
    cols = jnp.arange(restart)
    used = cols < m
    R = H[:restart] + jnp.diag(jnp.where(used, 0.0, 1.0).astype(dtype))
    coefficients = solve_triangular(R, jnp.where(used, g[:restart], 0.0), lower=False)
    return coefficients @ V[:restart], jnp.abs(g[m]), m


def gmres(matvec, b, tol, restart, max_cycles, x0=None, r0=None):
    r"""Solve $A x = b$ ($A$ = `matvec`) until $\|b - A x\|_2 \le$ `tol`, restarting
    every `restart` products, for at most `max_cycles` cycles. `x0` and its residual `r0`
    (both or neither; default 0 and `b`, which costs no product).

    Returns `(x, converged, products)`. `converged` reads the recurrence's residual, which
    equals the true one in exact arithmetic; a restart recomputes the true residual."""
    if x0 is None:
        x0, r0 = jnp.zeros_like(b), b

    def cond(c):
        _, _, beta, cycles, _ = c
        return (cycles < max_cycles) & (beta > tol)

    def body(c):
        x, r, beta, cycles, products = c
        dx, estimate, m = _cycle(matvec, r, beta, tol, restart)
        x = x + dx
        again = (estimate > tol) & (cycles + 1 < max_cycles)
        r = lax.cond(again, lambda: b - matvec(x), lambda: r)
        beta = jnp.where(again, jnp.linalg.norm(r), estimate)
        return x, r, beta, cycles + 1, products + m + again.astype(jnp.int32)

    beta0 = jnp.linalg.norm(r0)
    init = (x0, r0, beta0, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))
    x, _, beta, _, products = lax.while_loop(cond, body, init)
    return x, beta <= tol, products
