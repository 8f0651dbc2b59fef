"""Least-squares calibration: Levenberg–Marquardt (optimistix) on a residual vector whose
Jacobian is taken through the solver, with a Gauss–Newton covariance."""

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float, Int, PyTree


class FitResult(eqx.Module):
    r"""What [`nivpjax.fit`][] returns.

    **Fields:**

    - `params`: the estimate, a pytree like `params0`.
    - `residuals`: the residual vector at the estimate (flattened).
    - `cost`: $\frac12\|r\|^2$ at the estimate.
    - `jacobian`: $J = \partial r/\partial p$ at the estimate, `(m, p)` over the flattened
      parameters (the order of `jax.flatten_util.ravel_pytree(params0)`).
    - `sigma`: the noise level used: `sigma` if given, else the estimate
      $\hat\sigma = \|r\|/\sqrt{m - p}$.
    - `covariance`: the Gauss–Newton covariance $\sigma^2 (J^T J)^{-1}$ (pseudo-inverse: an
      unidentifiable direction gets zero rather than NaN; check `jacobian`'s rank).
    - `stderr`: the standard errors $\sqrt{\operatorname{diag}}$ of `covariance`, a pytree
      like `params0`.
    - `steps`: the number of solver steps taken.
    - `history`: $\frac12\|r\|^2$ at the start and after each step; NaN past `steps`.
    - `result`: an `optimistix.RESULTS` code (`successful`, or why not).
    """

    params: PyTree[Array]
    residuals: Float[Array, " m"]
    cost: Float[Array, ""]
    jacobian: Float[Array, "m p"]
    sigma: Float[Array, ""]
    covariance: Float[Array, "p p"]
    stderr: PyTree[Array]
    steps: Int[Array, ""]
    history: Float[Array, " k"]
    result: optx.RESULTS


def _check(params0, solver, max_steps, sigma):
    if not isinstance(max_steps, int) or isinstance(max_steps, bool) or max_steps < 1:
        raise ValueError(f"`max_steps` must be a positive int, got {max_steps!r}.")
    if not isinstance(solver, optx.AbstractLeastSquaresSolver):
        raise TypeError(
            "`solver` must be an optimistix least-squares solver (e.g. "
            f"optx.LevenbergMarquardt or optx.GaussNewton), got {solver!r}."
        )
    if sigma is not None and not isinstance(sigma, jax.core.Tracer) and not float(sigma) > 0:
        raise ValueError(f"`sigma` must be positive, got {sigma!r}.")
    leaves = jax.tree_util.tree_leaves(params0)
    if not leaves or not all(jnp.issubdtype(jnp.result_type(x), jnp.floating) for x in leaves):
        raise TypeError(
            f"`params0` must be a non-empty pytree of floating-point arrays, got {params0!r}."
        )


def fit(
    residual_fn: Callable[[PyTree[Array], Any], Array],
    params0: PyTree[Array],
    args: Any = None,
    *,
    solver: optx.AbstractLeastSquaresSolver | None = None,
    max_steps: int = 64,
    sigma=None,
    throw: bool = True,
) -> FitResult:
    r"""Minimise $\frac12\|r(p)\|^2$ over the parameters $p$, with $r$ = `residual_fn`,
    typically observations minus a [`nivpjax.solve`][] of the model at $p$.

    The solver (default `optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8)`) takes the
    Jacobian of `residual_fn` by forward-mode autodiff through the solve: one tangent per
    parameter, the cheap direction when there are few parameters and many observations.
    Derivatives across impacts, slip reversals and relay switches include their event-time
    (saltation) terms. Jittable and `vmap`-able (e.g. over several starting points when the
    loss has several minima); give such a `jax.jit` `compiler_options=nj.compiler_options()`
    for nivpjax's shorter CPU compile.

    **Arguments:**

    - `residual_fn`: `residual_fn(params, args) -> array` (any shape; flattened).
    - `params0`: the starting point, a pytree of floating-point arrays.
    - `args`: passed through to `residual_fn`.
    - `solver`: an optimistix least-squares solver (`LevenbergMarquardt`, `GaussNewton`,
      `Dogleg`, ...).
    - `max_steps`: the most solver steps.
    - `sigma`: the standard deviation of the observation noise, if known; otherwise it
      is estimated from the residuals (needs more residuals than parameters).
    - `throw`: raise if the solver did not converge (otherwise read `result`).

    **Returns:** a [`nivpjax.FitResult`][].

    **Raises:** `ValueError`/`TypeError` for bad arguments, before any work; with
    `throw=True`, an error at run time if the solver failed.
    """
    if solver is None:
        solver = optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8)
    _check(params0, solver, max_steps, sigma)
    p0, unravel = ravel_pytree(params0)

    def residual(p):
        return jnp.ravel(residual_fn(unravel(p), args)).astype(p.dtype)

    def fn(p, _):
        return residual(p), None

    def cost(p):
        return 0.5 * jnp.sum(residual(p) ** 2)

    f_struct = jax.eval_shape(residual, p0)
    tags = frozenset()
    state = solver.init(fn, p0, None, {}, f_struct, None, tags)
    done, result = solver.terminate(fn, p0, None, {}, state, tags)
    history = jnp.full((max_steps + 1,), jnp.nan, p0.dtype).at[0].set(cost(p0))

    # The solver state holds linearisations (jaxprs): carry only its arrays.
    dynamic, static = eqx.partition(state, eqx.is_array)

    def cond(carry):
        _, _, done, _, k, _ = carry
        return ~done & (k < max_steps)

    def body(carry):
        p, dynamic, _, _, k, history = carry
        state = eqx.combine(dynamic, static)
        p, state, _ = solver.step(fn, p, None, {}, state, tags)
        done, result = solver.terminate(fn, p, None, {}, state, tags)
        dynamic = eqx.filter(state, eqx.is_array)
        return p, dynamic, done, result, k + 1, history.at[k + 1].set(_cost_at(state, p, cost))

    init = (p0, dynamic, done, result, jnp.zeros((), jnp.int32), history)
    p, _, done, result, steps, history = jax.lax.while_loop(cond, body, init)
    result = optx.RESULTS.where(done, result, optx.RESULTS.nonlinear_max_steps_reached)
    if throw:
        p = result.error_if(p, result != optx.RESULTS.successful)
    return _finish(residual, p, unravel, sigma, steps, history, result)


def _cost_at(state, p, cost):
    # optimistix's Gauss-Newton family (GaussNewton, LevenbergMarquardt, Dogleg) keeps the
    # residual at the point its step returns in its state: reading it saves one solve per
    # iteration (and one copy of the solve in the compiled program). Other solvers
    # evaluate it.
    residual = getattr(getattr(state, "f_info", None), "residual", None)
    if residual is None:
        return cost(p)
    return 0.5 * jnp.sum(jnp.ravel(residual) ** 2)


def _finish(residual, p, unravel, sigma, steps, history, result):
    # The Jacobian's forward pass computes the residual too: one solve, not two.
    J, r = jax.jacfwd(lambda q: (lambda out: (out, out))(residual(q)), has_aux=True)(p)
    m, n = J.shape
    if sigma is None:
        sigma = jnp.sqrt(jnp.sum(r**2) / max(m - n, 1))
    sigma = jnp.asarray(sigma, p.dtype)
    covariance = sigma**2 * jnp.linalg.pinv(J.T @ J, hermitian=True)
    stderr = unravel(jnp.sqrt(jnp.maximum(jnp.diag(covariance), 0.0)))
    return FitResult(
        params=unravel(p),
        residuals=r,
        cost=0.5 * jnp.sum(r**2),
        jacobian=J,
        sigma=sigma,
        covariance=covariance,
        stderr=stderr,
        steps=steps,
        history=history,
        result=result,
    )
