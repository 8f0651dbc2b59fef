"""Dense solves of the small systems one step meets (a stage's Newton system, a contact
LCP's active set, a switching selection, a descriptor matrix)."""

import jax.numpy as jnp
import lineax as lx


# Up to this size a system is eliminated in unrolled array operations, which XLA fuses into
# a few kernels; larger ones go to LAPACK through lineax. On CPU a LAPACK LU of a 2 x 2
# system costs a dozen kernel launches (the factorisation, two triangular solves, layout
# copies) for a few flops, and a step solves several.
UNROLL_MAX = 8


def solve(A, b):
    """`(x, ok)`: the solution of `A x = b` (`A` of shape `(n, n)`, `b` of shape `(n,)`)
    by LU with partial pivoting, and whether it is usable (every pivot nonzero, `x`
    finite). Differentiable in `A` and `b`; where `ok` is false, `x` is finite but
    meaningless for the unrolled path and whatever LAPACK returned otherwise."""
    if A.shape[-1] > UNROLL_MAX:
        sol = lx.linear_solve(lx.MatrixLinearOperator(A), b, lx.LU(), throw=False)
        ok = (sol.result == lx.RESULTS.successful) & jnp.all(jnp.isfinite(sol.value))
        return sol.value, ok
    x, nonsingular = _unrolled(A, b)
    return x, nonsingular & jnp.all(jnp.isfinite(x))


def solve_or_nan(A, b):
    """`jnp.linalg.solve(A, b)` for one system: NaN where `A` is singular. Linear in `b`
    (the test reads `A` only), so it may stand in a JVP rule that reverse mode transposes."""
    if A.shape[-1] > UNROLL_MAX:
        return jnp.linalg.solve(A, b)
    x, nonsingular = _unrolled(A, b)
    return jnp.where(nonsingular, x, jnp.nan)


def _unrolled(A, b):
    lu, perm, nonsingular = _factor(A)
    return _substitute(lu, perm, b), nonsingular


def _factor(A):
    # Doolittle LU with partial pivoting, P A = L U, L unit lower triangular stored below
    # the diagonal. Row swaps are selects, so the whole factorisation fuses.
    n = A.shape[0]
    rows = jnp.arange(n)
    perm = rows
    nonsingular = jnp.array(True)
    for k in range(n):
        column = jnp.where(rows >= k, jnp.abs(A[:, k]), -1.0)
        p = jnp.argmax(column)
        swap_k, swap_p = (rows == k)[:, None], (rows == p)[:, None]
        A = jnp.where(swap_k, A[p], jnp.where(swap_p, A[k], A))
        perm = jnp.where(rows == k, perm[p], jnp.where(rows == p, perm[k], perm))
        pivot = A[k, k]
        nonsingular = nonsingular & (pivot != 0)
        below = rows > k
        factors = jnp.where(below, A[:, k] / jnp.where(pivot != 0, pivot, 1.0), 0.0)
        A = A - factors[:, None] * jnp.where(below, A[k], 0.0)[None, :]  # columns > k
        A = A.at[:, k].set(jnp.where(below, factors, A[:, k]))
    return A, perm, nonsingular


def _substitute(lu, perm, b):
    # Linear in `b` with constant coefficients, selects and gathers only: transposable, as
    # `lax.custom_root` needs of its tangent solve in reverse mode.
    rows = jnp.arange(b.shape[0])
    x = b[perm]
    for k in range(b.shape[0]):
        x = x - jnp.where(rows > k, lu[:, k], 0.0) * x[k]
    for k in reversed(range(b.shape[0])):
        pivot = lu[k, k]
        xk = x[k] / jnp.where(pivot != 0, pivot, 1.0)
        x = jnp.where(rows == k, xk, x - jnp.where(rows < k, lu[:, k], 0.0) * xk)
    return x
