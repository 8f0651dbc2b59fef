"""Semismooth Newton with a watchdog Armijo line search."""

import equinox as eqx
import jax.numpy as jnp
from jax import lax

from .._custom_types import plain_int
from .._linear import AbstractLinearSolver, AutoLinear
from .base import (
    AbstractNonlinearSolver,
    init_history,
    linearised_natural_map,
    natural_map,
    natural_map_and_argument,
    scaled_error,
)


class SemismoothNewton(AbstractNonlinearSolver):
    r"""Semismooth Newton on $G(y) = y - P(y - \rho R(y))$.

    Each iteration solves $G'(y)\,d = -G(y)$ with $G'$ the generalised Jacobian
    $I - D(I - \rho J_R)$ (the projectors' custom JVPs supply $D$), by `linear_solver`:
    by default ([`nivpjax.AutoLinear`][]) the Jacobian formed by forward-mode
    differentiation and solved densely (LU with partial pivoting: unrolled up to 8
    unknowns, lineax beyond) for small systems, and matrix-free Krylov solves with
    Eisenstat-Walker forcing terms ([`nivpjax.Krylov`][]) for large ones. It globalises
    with a backtracking Armijo line search on the merit $\tfrac12|G|^2$: accept $\alpha$
    when $\tfrac12|G(y + \alpha d)|^2 \le (1 - 2\sigma\alpha)\tfrac12|G(y)|^2$.

    The first `full_steps` iterations take the full Newton step whenever it is finite
    (a watchdog): a monotone line search stalls on stiffly coupled switching systems whose
    residual must grow before it collapses. If the Newton system is singular the iteration
    falls back to the projection step $d = -G(y)$. Converges locally superlinearly for
    semismooth $G$ with nonsingular generalised Jacobians (Qi & Sun, 1993).

    **Arguments:**

    - `rtol`, `atol`: stop when $\max_i |G_i| / (\text{atol} + \text{rtol}|y_i|) \le 1$,
      after at least one iteration. Inside a solve the loop tightens both to 1e-3 times
      the step's error control's where that is tighter
      ([`within`][nivpjax.AbstractNonlinearSolver.within]): defaults 1e-8 and 1e-10
      hold from a controller's rtol 1e-5 and atol 1e-7 up.
    - `max_steps`: cap on Newton iterations.
    - `full_steps`: number of initial iterations without line search.
    - `sigma`, `beta`, `max_backtracks`: Armijo constant, backtracking factor and cap.
    - `linear_solver`: an [`nivpjax.AbstractLinearSolver`][] for the Newton systems and
      the implicit-function solve of derivatives (default [`nivpjax.AutoLinear`][]).
    """

    rtol: float = 1e-8
    atol: float = 1e-10
    max_steps: int = eqx.field(static=True, default=50, converter=plain_int)
    full_steps: int = eqx.field(static=True, default=3)
    sigma: float = 1e-4
    beta: float = 0.5
    max_backtracks: int = eqx.field(static=True, default=30)
    linear_solver: AbstractLinearSolver = eqx.field(default_factory=AutoLinear)

    def _iterate(self, residual, project, rho, y0, rtol, atol):
        G = natural_map(residual, project, rho)
        Gz = natural_map_and_argument(residual, project, rho)
        G0, z0 = Gz(y0)
        linear = self.linear_solver.resolve(y0.shape[0])

        def merit(g):
            return 0.5 * jnp.sum(g**2)

        def cond(carry):
            (y, g, z), k, history, _, _ = carry
            return (
                (k < self.max_steps)
                # At least one iteration: with a tiny step the whole update of the stage can
                # lie below the tolerance, and stopping at the initial guess would freeze
                # the state (with a zero error estimate, so the controller cannot notice).
                & ((k == 0) | (scaled_error(g, y, rtol, atol, z) > 1))
                & jnp.all(jnp.isfinite(g))
            )

        def body(carry):
            (y, g, z), k, history, state, linear_its = carry
            linearize = lambda: linearised_natural_map(residual, project, rho, y, z)
            scale = atol + rtol * jnp.abs(y)
            d, ok, its, state = linear.direction(G, y, g, scale, state, linearize)
            d = jnp.where(ok, d, -g)
            m0 = merit(g)
            watchdog = k < self.full_steps

            def ls_cond(ls):
                alpha, y_try, (g_try, _), j = ls
                m_try = merit(g_try)
                finite = jnp.all(jnp.isfinite(g_try))
                good = finite & (watchdog | (m_try <= (1 - 2 * self.sigma * alpha) * m0))
                return ~good & (j < self.max_backtracks)

            def ls_body(ls):
                alpha, _, _, j = ls
                alpha = self.beta * alpha
                y_try = y + alpha * d
                return alpha, y_try, Gz(y_try), j + 1

            one = jnp.ones((), y.dtype)
            y1 = y + d
            _, y_new, (g_new, z_new), _ = lax.while_loop(ls_cond, ls_body, (one, y1, Gz(y1), 0))
            k = k + 1
            history = history.at[k].set(jnp.max(jnp.abs(g_new), initial=0.0))
            return (y_new, g_new, z_new), k, history, state, linear_its + its

        history = init_history(self.max_steps, y0.dtype, jnp.max(jnp.abs(G0), initial=0.0))
        init = ((y0, G0, z0), jnp.array(0), history, linear.init(y0), jnp.zeros((), jnp.int32))
        (y, _, _), k, history, _, linear_its = lax.while_loop(cond, body, init)
        return y, (k.astype(y.dtype), history, linear_its.astype(y.dtype))
