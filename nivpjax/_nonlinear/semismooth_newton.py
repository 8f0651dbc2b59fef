"""Semismooth Newton with a watchdog Armijo line search."""

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax

from .._custom_types import plain_int
from .base import AbstractNonlinearSolver, dense_solve, init_history, natural_map, scaled_error


class SemismoothNewton(AbstractNonlinearSolver):
    r"""Semismooth Newton on $G(y) = y - P(y - \rho R(y))$.

    Each iteration forms the generalised Jacobian $I - D(I - \rho J_R)$ by forward-mode
    differentiation of $G$ (the projectors' custom JVPs supply $D$; one pass gives $G$ and
    its Jacobian at each trial point), solves densely (LU with partial pivoting: unrolled
    array operations up to 8 unknowns, lineax beyond), and globalises with a backtracking
    Armijo line search on the merit
    $\tfrac12|G|^2$: accept $\alpha$ when
    $\tfrac12|G(y + \alpha d)|^2 \le (1 - 2\sigma\alpha)\tfrac12|G(y)|^2$.

    The first `full_steps` iterations take the full Newton step whenever it is finite
    (a watchdog): a monotone line search stalls on stiffly coupled switching systems whose
    residual must grow before it collapses. If the Newton system is singular the iteration
    falls back to the projection step $d = -G(y)$. Converges locally superlinearly for
    semismooth $G$ with nonsingular generalised Jacobians (Qi & Sun, 1993).

    **Arguments:**

    - `rtol`, `atol`: stop when $\max_i |G_i| / (\text{atol} + \text{rtol}|y_i|) \le 1$,
      after at least one iteration.
    - `max_steps`: cap on Newton iterations.
    - `full_steps`: number of initial iterations without line search.
    - `sigma`, `beta`, `max_backtracks`: Armijo constant, backtracking factor and cap.
    """

    rtol: float = 1e-8
    atol: float = 1e-10
    max_steps: int = eqx.field(static=True, default=50, converter=plain_int)
    full_steps: int = eqx.field(static=True, default=3)
    sigma: float = 1e-4
    beta: float = 0.5
    max_backtracks: int = eqx.field(static=True, default=30)

    def _iterate(self, residual, project, rho, y0, rtol, atol):
        G = natural_map(residual, project, rho)

        def value_and_jacobian(y):
            # One forward-mode pass: G's value and its generalised Jacobian together.
            def both(v):
                g = G(v)
                return g, g

            J, g = jax.jacfwd(both, has_aux=True)(y)
            return g, J

        def direction(g, J):
            d, ok = dense_solve(J, -g)
            return jnp.where(ok, d, -g)

        def merit(g):
            return 0.5 * jnp.sum(g**2)

        def cond(carry):
            y, g, _, _, k, _, _ = carry
            return (
                (k < self.max_steps)
                # At least one iteration: with a tiny step the whole update of the stage can
                # lie below the tolerance, and stopping at the initial guess would freeze
                # the state (with a zero error estimate, so the controller cannot notice).
                & ((k == 0) | (scaled_error(g, y, rtol, atol) > 1))
                & jnp.all(jnp.isfinite(g))
            )

        def body(carry):
            # One trial point: the Newton step from the last accepted iterate `y`, scaled by
            # `alpha`. Accepted (a Newton iteration) when the watchdog allows the full step
            # or the merit falls enough, or after `max_backtracks` backtracks; otherwise
            # `alpha` shrinks. The line search is this same loop, so each trial costs one
            # forward pass, which also yields the next Newton direction.
            y, g, d, alpha, k, j, history = carry
            y_try = y + alpha * d
            g_try, J_try = value_and_jacobian(y_try)
            watchdog = k < self.full_steps
            sufficient = merit(g_try) <= (1 - 2 * self.sigma * alpha) * merit(g)
            good = jnp.all(jnp.isfinite(g_try)) & (watchdog | sufficient)
            accept = good | (j >= self.max_backtracks)
            k_new = k + accept.astype(k.dtype)
            norm = jnp.max(jnp.abs(g_try), initial=0.0)
            drop = jnp.where(accept, k_new, self.max_steps + 1)
            return (
                jnp.where(accept, y_try, y),
                jnp.where(accept, g_try, g),
                jnp.where(accept, direction(g_try, J_try), d),
                jnp.where(accept, 1.0, self.beta * alpha).astype(alpha.dtype),
                k_new,
                jnp.where(accept, 0, j + 1),
                history.at[drop].set(norm, mode="drop"),
            )

        g0, J0 = value_and_jacobian(y0)
        history = init_history(self.max_steps, y0.dtype, jnp.max(jnp.abs(g0), initial=0.0))
        one = jnp.ones((), y0.dtype)
        init = (y0, g0, direction(g0, J0), one, jnp.array(0), jnp.array(0), history)
        y, _, _, _, k, _, history = lax.while_loop(cond, body, init)
        return y, (k.astype(y.dtype), history)
