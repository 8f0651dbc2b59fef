"""Dense solves of the small systems one step meets (a stage's Newton system, a contact
LCP's active set, a switching selection, a descriptor matrix)."""

import jax
import jax.numpy as jnp
from jax import lax


# Up to this size a system is eliminated in unrolled array operations, which XLA fuses into
# a few kernels; larger ones go to LAPACK through lineax. On CPU a LAPACK LU of a 2 x 2
# system costs a dozen kernel launches (the factorisation, two triangular solves, layout
# copies) for a few flops, and a step solves several.
UNROLL_MAX = 8

# No batched LAPACK factorisation is ever emitted. jaxlib 0.10's CPU kernels spread a
# batch of factorisations over the intra-op thread pool and block a pool thread until the
# pieces are done: as many batched factorisations running side by side as the pool has
# threads (two on a two-core machine) wait on each other for ever (measured: the outputs
# of the block on a cone, two vmapped 401 x 9 x 9 LUs, hung one run in two; all pool
# threads in `BlockingCounter::Wait` under `lapack_dgetrf_ffi`). A batch of systems of up
# to LOOP_MAX unknowns is eliminated in array operations across the batch (a loop over
# the columns); a batch of larger ones is one LAPACK call per system, in a loop.
LOOP_MAX = 64


def solve(A, b):
    """`(x, ok)`: the solution of `A x = b` (`A` of shape `(n, n)`, `b` of shape `(n,)`)
    by LU with partial pivoting, and whether it is usable (every pivot nonzero, `x`
    finite). Differentiable in `A` and `b`, linear in `b` (reverse mode transposes it);
    where `ok` is false, `x` is finite but meaningless for the unrolled path and whatever
    the factorisation gave otherwise."""
    if A.shape[-1] > UNROLL_MAX:
        x = _large(A, b)
        return x, jnp.all(jnp.isfinite(x))
    x, nonsingular = _unrolled(A, b)
    return x, nonsingular & jnp.all(jnp.isfinite(x))


def solve_or_nan(A, b):
    """`jnp.linalg.solve(A, b)` for one system: NaN where `A` is singular. Linear in `b`
    (the test reads `A` only), so it may stand in a JVP rule that reverse mode transposes."""
    if A.shape[-1] > UNROLL_MAX:
        return _large(A, b)
    x, nonsingular = _unrolled(A, b)
    return jnp.where(nonsingular, x, jnp.nan)


def inverse(A):
    """The inverse of `A` (`(n, n)`), by `solve_or_nan` on the identity's columns: NaN
    where `A` is singular, and no batched LAPACK call under `vmap`."""
    eye = jnp.eye(A.shape[-1], dtype=A.dtype)
    if A.shape[-1] > UNROLL_MAX:
        return _lapack(A, eye)
    return jax.vmap(lambda e: solve_or_nan(A, e), out_axes=1)(eye)


def _large(A, b):
    # Differentiated as a linear solve (`lax.custom_linear_solve`: the tangent and the
    # transpose are solves again, with A and with its transpose), so that `_lapack`'s
    # batching rule is all JAX sees of the factorisation.
    return lax.custom_linear_solve(
        lambda x: A @ x,
        b,
        lambda _, r: _lapack(A, r[:, None])[:, 0],
        lambda _, r: _lapack(A.T, r[:, None])[:, 0],
    )


@jax.custom_batching.custom_vmap
def _lapack(A, B):
    # `A X = B` for the columns of `B`: one LAPACK LU, NaN or inf where a pivot is zero.
    return jax.scipy.linalg.lu_solve(jax.scipy.linalg.lu_factor(A), B)


@_lapack.def_vmap
def _lapack_batched(axis_size, in_batched, A, B):
    A_batched, B_batched = in_batched
    if not A_batched:  # one matrix: the batch's right-hand sides as more columns
        n, m = B.shape[1:]
        X = _lapack(A, jnp.moveaxis(B, 0, 1).reshape(n, axis_size * m))
        return jnp.moveaxis(X.reshape(n, axis_size, m), 1, 0), True
    B = B if B_batched else jnp.broadcast_to(B, (axis_size,) + B.shape)
    if A.shape[-1] <= LOOP_MAX:
        return jax.vmap(_looped)(A, B), True
    return lax.map(lambda AB: _lapack(*AB), (A, B)), True


def _looped(A, B):
    # The unrolled elimination's steps in a loop over the columns (a batch of systems
    # under `vmap` runs each step across the batch): NaN where a pivot is zero.
    lu, perm, nonsingular = _factor(A, unroll=False)
    X = jax.vmap(lambda b: _substitute(lu, perm, b, unroll=False), in_axes=1, out_axes=1)(B)
    return jnp.where(nonsingular, X, jnp.nan)


def _unrolled(A, b):
    lu, perm, nonsingular = _factor(A)
    return _substitute(lu, perm, b), nonsingular


def _factor(A, unroll=True):
    # Doolittle LU with partial pivoting, P A = L U, L unit lower triangular stored below
    # the diagonal. Row swaps are selects, so the whole factorisation fuses.
    rows = jnp.arange(A.shape[0])

    def column(k, carry):
        A, perm, nonsingular = carry
        p = jnp.argmax(jnp.where(rows >= k, jnp.abs(A[:, k]), -1.0))
        swap_k, swap_p = (rows == k)[:, None], (rows == p)[:, None]
        A = jnp.where(swap_k, A[p], jnp.where(swap_p, A[k], A))
        perm = jnp.where(rows == k, perm[p], jnp.where(rows == p, perm[k], perm))
        pivot = A[k, k]
        below = rows > k
        factors = jnp.where(below, A[:, k] / jnp.where(pivot != 0, pivot, 1.0), 0.0)
        A = A - factors[:, None] * jnp.where(below, A[k], 0.0)[None, :]  # columns > k
        A = A.at[:, k].set(jnp.where(below, factors, A[:, k]))
        return A, perm, nonsingular & (pivot != 0)

    return _columns(A.shape[0], column, (A, rows, jnp.array(True)), unroll)


def _substitute(lu, perm, b, unroll=True):
    # Linear in `b` with constant coefficients, selects and gathers only: transposable, as
    # `lax.custom_root` needs of its tangent solve in reverse mode.
    n = b.shape[0]
    rows = jnp.arange(n)

    def forward(k, x):
        return x - jnp.where(rows > k, lu[:, k], 0.0) * x[k]

    def backward(j, x):
        k = n - 1 - j
        pivot = lu[k, k]
        xk = x[k] / jnp.where(pivot != 0, pivot, 1.0)
        return jnp.where(rows == k, xk, x - jnp.where(rows < k, lu[:, k], 0.0) * xk)

    x = _columns(n, forward, b[perm], unroll)
    return _columns(n, backward, x, unroll)


def _columns(n, body, carry, unroll):
    # `body(k, carry)` for k = 0, ..., n - 1: unrolled, or a loop.
    if not unroll:
        return lax.fori_loop(0, n, body, carry)
    for k in range(n):
        carry = body(k, carry)
    return carry
