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

    def plain(p):
        return jnp.ravel(residual_fn(unravel(p), args)).astype(p.dtype)

    residual = _jacobian_once(plain)

    def fn(p, _):
        return residual(p), None

    def cost(p):
        return 0.5 * jnp.sum(residual(p) ** 2)

    p, state, steps, history, result = _iterate(solver, fn, cost, p0, max_steps)
    if throw:
        p = result.error_if(p, result != optx.RESULTS.successful)
    info = _kept(state)
    if info is None:
        J, r = _jacobian_and_value(plain, p)
    else:
        J, r = info.jac.as_matrix(), jnp.ravel(info.residual)
    return _finish(J, r, p, unravel, sigma, steps, history, result)


def _iterate(solver, fn, cost, p0, max_steps):
    f_struct = jax.eval_shape(lambda p: fn(p, None)[0], p0)
    tags = frozenset()
    state = solver.init(fn, p0, None, {}, f_struct, None, tags)
    done, result = solver.terminate(fn, p0, None, {}, state, tags)
    # The Gauss-Newton family keeps the residual and the linearisation at the point its
    # step returns (`_kept`); its first step returns `params0` itself, so the start's cost
    # is the first step's. Reading them instead of evaluating keeps one linearised solve
    # in the compiled program, not three (the compile time a calibration pays).
    kept = _kept(state) is not None
    history = jnp.full((max_steps + 1,), jnp.nan, p0.dtype)
    history = history.at[0].set(jnp.nan if kept else cost(p0))
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
        if kept:
            c = 0.5 * jnp.sum(jnp.ravel(_kept(state).residual) ** 2)
            history = history.at[0].set(jnp.where(k == 0, c, history[0]))
        else:
            c = cost(p)
        history = history.at[k + 1].set(c)
        return p, eqx.filter(state, eqx.is_array), done, result, k + 1, history

    init = (p0, dynamic, done, result, jnp.zeros((), jnp.int32), history)
    p, dynamic, done, result, steps, history = jax.lax.while_loop(cond, body, init)
    result = optx.RESULTS.where(done, result, optx.RESULTS.nonlinear_max_steps_reached)
    return p, eqx.combine(dynamic, static), steps, history, result


def _jacobian_and_value(residual, p):
    # The Jacobian's forward pass computes the residual too: one solve, not two.
    return jax.jacfwd(lambda q: (lambda out: (out, out))(residual(q)), has_aux=True)(p)


def _jacobian_once(residual):
    # The residual with a JVP rule that materialises the Jacobian (one tangent per
    # parameter, forward mode through the solve) and applies it. A linearisation of it
    # keeps J as a constant, so the solver's several uses of the linear map (its
    # materialisation, the trust region's predicted reduction, the covariance) are
    # products with J, not copies of the solve's tangent program.
    @jax.custom_jvp
    def wrapped(p):
        return residual(p)

    @wrapped.defjvp
    def _jvp(primals, tangents):
        (p,), (dp,) = primals, tangents
        J, r = _jacobian_and_value(residual, p)
        return r, J @ dp

    return wrapped


def _kept(state):
    # optimistix's Gauss-Newton family (GaussNewton, LevenbergMarquardt, Dogleg) keeps the
    # residual at the point its step returns, and its linearisation there, in `f_info`.
    # Other solvers (BestSoFarLeastSquares, ...) keep something else: None.
    info = getattr(state, "f_info", None)
    if isinstance(info, optx.FunctionInfo.ResidualJac):
        return info
    return None


def _finish(J, r, p, unravel, sigma, steps, history, result):
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
