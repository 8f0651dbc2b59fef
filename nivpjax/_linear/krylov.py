r"""Inexact, matrix-free Newton directions: Krylov solves on the residual linearised at the
iterate, with Eisenstat-Walker forcing terms."""

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
from jax import lax

from .._custom_types import plain_int
from .base import AbstractLinearSolver
from .gmres import gmres
from .preconditioner import AbstractPreconditioner


_METHODS = ("gmres", "bicgstab")


class _ForcingState(eqx.Module):
    g_norm: jax.Array  # |G| at the previous iterate (inf before the first)
    eta: jax.Array  # the previous forcing term
    z: jax.Array  # the previous direction in the preconditioned variable (warm start)


class Krylov(AbstractLinearSolver):
    r"""Matrix-free Newton directions: the linearisation of the natural map at the iterate
    gives $v \mapsto G'(y)\,v$ (`jax.linearize`, or semismooth Newton's from the
    projection argument it already holds, which spares a residual; one product costs
    about one residual evaluation; the linearisation fixes the branch of every kink, so
    the operator is exactly linear, with the projectors' selected elements), and a Krylov
    method solves $G'(y)\,d = -G(y)$ to the relative accuracy $\eta_k$. Nothing of size
    $n^2$ is formed: the cost of an iteration grows like the cost of the residual.

    - GMRES (the default) is nivpjax's own restarted GMRES(m): its Givens recurrence
      gives the residual after every product, and it stops at the first product with
      $\|G'(y)\,d + G(y)\|_2 \le \eta_k \|G(y)\|_2$. (lineax's GMRES fills its whole
      Krylov space before it tests, and spends a product on the initial residual: on the
      fault at 20 x 20 cells a Newton iteration cost 7 products where 2.4 sufficed.)
    - BiCGStab is lineax's, tested componentwise:
      $\|G'(y)\,d + G(y)\|_\infty \le \eta_k \|G(y)\|_\infty$.

    **Forcing terms** (Eisenstat & Walker 1996, choice 2): $\eta_0$ = `eta0`, then
    $\eta_k = \gamma (\|G_k\| / \|G_{k-1}\|)^{\alpha}$ (in the method's norm), kept at least
    $\gamma \eta_{k-1}^{\alpha}$ when that exceeds 0.1 (no sudden over-solving after one
    lucky iteration), at most `eta_max`, and at least $\tfrac12 \tau / \|G_k\|$ with
    $\tau$ the smallest tolerance of the nonlinear test (no accuracy beyond what ends the
    iteration; Kelley 1995). Early iterations are solved loosely, the last ones
    accurately enough for superlinear convergence.

    **Warm start** (`warm_start=True`, off by default): the previous iteration's
    direction, rescaled by $\|G_k\| / \|G_{k-1}\|$, when it leaves a smaller linear
    residual than zero (one product to check). On the spring-block chain it saved no
    Krylov iterations and cost the product.

    **Preconditioning** (right: $G' M z = -G$, $d = M z$, so the stopping test reads the
    true residual): `None`, or an [`nivpjax.AbstractPreconditioner`][] such as
    [`nivpjax.BlockJacobi`][], rebuilt at every iteration from products of $G'(y)$.

    **Failure:** a Krylov solve that stops short of its tolerance still returns its
    iterate; Newton uses it if it is finite (a line search follows, and only the
    nonlinear test can declare the stage solved, so an inaccurate direction costs
    iterations, never a wrong `successful`). The implicit-function solve of derivatives
    is held to `tangent_rtol`; if it does not get there its result is NaN, in forward and
    in reverse mode, never a wrong finite derivative.

    **Arguments:**

    - `method`: `"gmres"` (restarted GMRES, the default: robust for nonsymmetric
      Jacobians) or `"bicgstab"` (two products per iteration, short recurrences).
    - `restart`: GMRES's largest Krylov space per cycle; a restart costs one product
      (the true residual). A cycle that meets the tolerance early stops there, but the
      basis is stored whole and orthogonalised against in full, so a long cycle costs
      memory and time even when unused: 5 suits well-conditioned stages (on the fault
      at 20 x 20 cells 10 and 20 were 10-25% slower); raise it for stiff, strongly
      coupled stages, where short restarts stagnate.
    - `max_steps`: GMRES cycles, or BiCGStab iterations, per solve.
    - `eta0`, `eta_max`, `gamma`, `alpha`: the forcing terms above.
    - `warm_start`: whether to try the previous direction as the initial guess.
    - `preconditioner`: see above.
    - `tangent_rtol`: relative accuracy of the implicit-function solve (clamped to
      $100\epsilon$ of the dtype); `tangent_max_steps`: its cap (cycles or iterations).
    """

    method: str = eqx.field(static=True, default="gmres")
    restart: int = eqx.field(static=True, default=5, converter=plain_int)
    max_steps: int = eqx.field(static=True, default=40, converter=plain_int)
    eta0: float = 0.5
    eta_max: float = 0.9
    gamma: float = 0.9
    alpha: float = 2.0
    warm_start: bool = eqx.field(static=True, default=False)
    preconditioner: AbstractPreconditioner | None = None
    tangent_rtol: float = 1e-10
    tangent_max_steps: int = eqx.field(static=True, default=100, converter=plain_int)

    def __check_init__(self):
        if self.method not in _METHODS:
            raise ValueError(f"`method` must be one of {_METHODS}, got {self.method!r}.")
        for name in ("restart", "max_steps", "tangent_max_steps"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"`{name}` must be a positive int, got {value!r}.")
        for name in ("eta0", "eta_max", "gamma"):
            value = getattr(self, name)
            if isinstance(value, (int, float)) and not 0 < value < 1:
                raise ValueError(f"`{name}` must lie in (0, 1), got {value!r}.")
        if isinstance(self.alpha, (int, float)) and not 1 < self.alpha <= 2:
            raise ValueError(f"`alpha` must lie in (1, 2], got {self.alpha!r}.")
        if self.preconditioner is not None and not isinstance(
            self.preconditioner, AbstractPreconditioner
        ):
            raise TypeError(
                "`preconditioner` must be None or an nivpjax.AbstractPreconditioner, got "
                f"{self.preconditioner!r}."
            )

    def init(self, y):
        inf = jnp.full((), jnp.inf, y.dtype)
        return _ForcingState(g_norm=inf, eta=jnp.asarray(self.eta0, y.dtype), z=jnp.zeros_like(y))

    def _forcing(self, g_norm, scale, state):
        dtype = g_norm.dtype
        first = ~jnp.isfinite(state.g_norm)
        ratio = g_norm / jnp.where(first | (state.g_norm == 0), 1.0, state.g_norm)
        eta = self.gamma * ratio**self.alpha
        guard = self.gamma * state.eta**self.alpha
        eta = jnp.where(guard > 0.1, jnp.maximum(eta, guard), eta)
        eta = jnp.where(first, self.eta0, eta)
        floor = 0.5 * jnp.min(scale) / jnp.where(g_norm > 0, g_norm, 1.0)
        eta = jnp.minimum(jnp.maximum(eta, floor), self.eta_max)
        return jnp.maximum(eta, 100 * jnp.finfo(dtype).eps).astype(dtype)

    def _norm(self, g):
        # GMRES tests the 2-norm, which its recurrence gives after every product; lineax's
        # BiCGStab tests components (see `_solve`).
        if self.method == "gmres":
            return jnp.linalg.norm(g)
        return jnp.max(jnp.abs(g), initial=0.0)

    def direction(self, G, y, g, scale, state, linearize=None):
        lin = jax.linearize(G, y)[1] if linearize is None else linearize()
        g_norm = self._norm(g)
        eta = self._forcing(g_norm, scale, state)
        apply, _ = self._preconditioner(lin, y)
        operator = lambda z: lin(apply(z))
        b = -g
        z0, r0 = jnp.zeros_like(y), b
        if self.warm_start:
            prev = state.g_norm
            shrink = jnp.where(jnp.isfinite(prev) & (prev > 0), g_norm / prev, 0.0)
            guess = state.z * shrink
            r_guess = b - operator(guess)
            better = self._norm(r_guess) < self._norm(b)
            z0, r0 = jnp.where(better, guess, z0), jnp.where(better, r_guess, r0)
        if self.method == "gmres":
            z, _, iterations = gmres(
                operator, b, eta * g_norm, self.restart, self.max_steps, z0, r0
            )
        else:
            z, _, iterations = self._solve(operator, b, eta, self.max_steps, z0)
        d = apply(z)
        ok = jnp.all(jnp.isfinite(d))
        z = jnp.where(ok, z, 0.0)
        return d, ok, iterations, _ForcingState(g_norm=g_norm, eta=eta, z=z)

    def _preconditioner(self, matvec, y):
        if self.preconditioner is None:
            return (lambda v: v), (lambda v: v)
        return self.preconditioner.build(matvec, y.shape[0], y.dtype)

    def _solve(self, operator, b, rtol, max_steps, z0):
        # lineax stops when |r_i| <= atol + rtol |b_i| for every i, which no zero component
        # of b can meet with rtol alone: we want |r| <= rtol |b| in norm, so atol =
        # rtol |b|_inf and rtol = 0. lineax also asks that the last update of the solution
        # be below the same scale (a Cauchy test, which costs an extra iteration or cycle
        # and is no part of the inexact Newton condition): solving for w = z / c with the
        # operator c A (the same Krylov spaces, the same residuals) makes updates c times
        # smaller, so the residual test alone decides.
        c = 1.0 / jnp.sqrt(jnp.finfo(b.dtype).eps)
        b_norm = jnp.max(jnp.abs(b), initial=0.0)
        atol = rtol * jnp.where(b_norm > 0, b_norm, 1.0)
        if self.method == "gmres":
            solver = lx.GMRES(rtol=0.0, atol=atol, restart=self.restart, max_steps=max_steps)
        else:
            solver = lx.BiCGStab(rtol=0.0, atol=atol, max_steps=max_steps)
        structure = jax.ShapeDtypeStruct(b.shape, b.dtype)
        op = lx.FunctionLinearOperator(lambda w: operator(c * w), structure)
        sol = lx.linear_solve(op, b, solver, options={"y0": z0 / c}, throw=False)
        steps = sol.stats["num_steps"]
        if self.method == "gmres":
            # A GMRES step is a cycle of `restart` products; lineax's first is a dummy.
            iterations = jnp.maximum(steps - 1, 0) * self.restart
        else:
            iterations = steps
        converged = sol.result == lx.RESULTS.successful
        return c * sol.value, converged, jnp.asarray(iterations, jnp.int32)

    def tangent_solve(self, g, b):
        rtol = jnp.maximum(jnp.asarray(self.tangent_rtol, b.dtype), 100 * jnp.finfo(b.dtype).eps)
        apply, apply_t = self._preconditioner(g, b)

        def solve(matvec, rhs, precondition):
            z, converged, _ = self._solve(
                lambda v: matvec(precondition(v)),
                rhs,
                rtol,
                self.tangent_max_steps,
                jnp.zeros_like(rhs),
            )
            # Masked with a constant predicate (the solve's success is not differentiated),
            # so the result stays linear in `rhs`.
            return jnp.where(lax.stop_gradient(converged), precondition(z), jnp.nan)

        return lax.custom_linear_solve(
            g,
            b,
            solve=lambda matvec, rhs: solve(matvec, rhs, apply),
            transpose_solve=lambda vecmat, rhs: solve(vecmat, rhs, apply_t),
        )
