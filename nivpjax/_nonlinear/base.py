"""Interface of the nonlinear solvers for one implicit stage."""

import abc
import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float, Int

from .._linear import AbstractLinearSolver
from .._results import RESULTS
from .._tangent import tangent_only


Residual = Callable[[Array], Array]
Project = Callable[[Array, Array, Array], Array]


class NonlinearSolution(eqx.Module):
    """What a nonlinear solve returns.

    **Fields:**

    - `value`: the solution: the final iterate $y$, with the components the projector
      moves (or where $y$ itself lies outside the set) replaced by those of
      $P(y - \\rho R(y))$, so constrained components lie exactly in their sets, converged
      or not (bit-exactly for boxes, sign sets and orthants; the ball's and the cone's
      boundary points are computed in rounded arithmetic, to an ulp or two), differentiable
      through the implicit function theorem.
    - `iterations`: number of outer iterations taken.
    - `residual_norm`: $\\|G(y)\\|_\\infty$ at the returned value, with
      $G(y) = y - P(y - \\rho R(y))$ at the problem's own $\\rho$.
    - `result`: a [`nivpjax.RESULTS`][] code; `successful` iff the scaled residual met the
      tolerance.
    - `history`: a residual norm after each iteration, entries past `iterations` NaN
      ("not reached"). Semismooth Newton records $\\|G\\|_\\infty$ (entry 0: the initial
      guess); the VI method records its natural residual (entry 0 is NaN).
    - `linear_iterations`: Krylov iterations summed over the Newton iterations (0 for
      dense solves and the VI method).
    """

    value: Float[Array, " n"]
    iterations: Int[Array, ""]
    residual_norm: Float[Array, ""]
    result: RESULTS
    history: Float[Array, " k"]
    linear_iterations: Int[Array, ""] = eqx.field(default_factory=lambda: jnp.zeros((), jnp.int32))


def natural_map_and_argument(residual: Residual, project: Project, rho):
    """`y -> (G(y), z)`: the natural map and the projection's argument $z = y - \\rho R(y)$,
    whose size sets the round-off of $G$ (`scaled_error`'s `z`)."""

    def G(y):
        z = y - rho * residual(y)
        return y - project(z, y, rho), z

    return G


def natural_map(residual: Residual, project: Project, rho) -> Callable[[Array], Array]:
    """$G(y) = y - P(y - \\rho R(y); y, \\rho)$: zero exactly at solutions of the stage's VI."""
    G = natural_map_and_argument(residual, project, rho)
    return lambda y: G(y)[0]


def linearised_natural_map(residual: Residual, project: Project, rho, y, z):
    r"""$v \mapsto G'(y)\,v$ at an iterate whose projection argument
    $z = y - \rho R(y)$ is already known: the same linear map as `jax.linearize` of
    [`natural_map`][] at $y$, $v - \partial_z P\,(v - \rho R'(y) v) - \partial_y P\,v$,
    without evaluating $R(y)$ again (its value is unused, so XLA drops it; on the fault's
    dense kernel that is two of a Newton iteration's four to five kernel products)."""
    _, dR = jax.linearize(residual, y)
    _, dP = jax.linearize(lambda z_, y_: project(z_, y_, rho), z, y)
    return lambda v: v - dP(v - rho * dR(v), v)


# The round-off of G = y - P(z) on a component where the projection cancels a large
# argument z: a few ulps of |z|. A multiplier the state does not determine (a cone's
# reaction on a block in slip at t0, theta = 0: a whole ray of solutions) sits at
# |G| = 4.5e-13 with |z| = 4e4 (rho 7e4), and rtol 1e-8 asked |G| <= 1e-13: Newton then
# alternated between that point and 4e4 for its 50 iterations and the run failed at its
# start. Elsewhere |z| is about |y| and the floor lies far below the tolerance.
ROUNDOFF_ULPS = 16
# The round-off of a residual's terms, in ulps of their size (`residual_scale`; a bound,
# the terms' magnitudes already add up).
RESIDUAL_ULPS = 4


def scaled_error(G_value, y, rtol, atol, z=None):
    """$\\max_i |G_i| / (\\text{atol} + \\text{rtol} |y_i| + 16\\,\\varepsilon |z_i|)$, with
    $z$ the projection's argument where given (the round-off floor of $G$); converged when
    $\\le 1$."""
    scale = atol + rtol * jnp.abs(y)
    if z is not None:
        scale = scale + ROUNDOFF_ULPS * jnp.finfo(jnp.result_type(y)).eps * jnp.abs(z)
    return jnp.max(jnp.abs(G_value) / scale, initial=0.0)


def residual_scale(residual, y):
    r"""$|J\,|y||$, $J$ the residual's Jacobian at $y$: the size of the terms the
    residual adds up, whose round-off bounds how small it can be made. A multiplier's
    row scaled by $\rho = 1/h$ (a relay's selection, whose residual is its switching
    function $\sigma(x)$) has a natural residual that round-off in $\sigma$ alone keeps
    at about $\varepsilon |x| / h$: at $h = 10^{-11}$ on super-twisting's sliding surface
    (x = 0.05, $\sigma = x_2 + x_1$) 3.5e-6, far above the stage's tolerance, and every
    solve ran out of iterations until the run's steps did."""
    return (RESIDUAL_ULPS / ROUNDOFF_ULPS) * jnp.abs(jax.jvp(residual, (y,), (jnp.abs(y),))[1])


# A stage's nonlinear solve is held at least this much tighter than the step's error
# control (`AbstractNonlinearSolver.within`): its error then stays far below the local error
# the controller accepts. At a solver's own default 1e-8 and a controller's rtol 1e-8, the
# fixed-point iteration (linear convergence, stopping at its tolerance) made the stick-slip
# slider's error 2x semismooth Newton's, or stalled; 1e-11 reproduced Newton's.
STAGE_FRACTION = 1e-3


def effective_tolerances(rtol, atol, dtype):
    """Tolerances clamped to what the dtype can resolve (a float32 solve asked for 1e-12
    would otherwise never converge). Python floats stay floats; arrays (tolerances from
    the step's error control, run-time values) are clamped as arrays."""
    floor = 8 * float(jnp.finfo(dtype).eps)
    if isinstance(rtol, (int, float)) and isinstance(atol, (int, float)):
        return max(float(rtol), floor), max(float(atol), floor)
    return (
        jnp.maximum(jnp.asarray(rtol, dtype), floor),
        jnp.maximum(jnp.asarray(atol, dtype), floor),
    )


class AbstractNonlinearSolver(eqx.Module):
    """Solves the variational inequality of one implicit stage: find $y$ with
    $y = P(y - \\rho R(y))$.

    Subclasses implement `_iterate`, a `lax.while_loop` returning the value and float
    diagnostics. `solve` wraps it in `jax.lax.custom_root`, so the returned value is
    differentiated by the implicit function theorem on $G(y) = 0$ (with the generalised
    Jacobian the projectors' custom JVP rules select), never by unrolling the iteration;
    `linear_solver` solves that linear system (see [`nivpjax.AutoLinear`][]).
    """

    rtol: eqx.AbstractVar[float]
    atol: eqx.AbstractVar[float]
    max_steps: eqx.AbstractVar[int]
    linear_solver: eqx.AbstractVar[AbstractLinearSolver]

    def within(self, rtol, atol):
        r"""This solver with its tolerances at most `STAGE_FRACTION` (1e-3) times `rtol`
        and `atol`, those of the step's error control (the loop calls it with the
        controller's `tolerances()`; its own stay where
        they are tighter). A stage solved only to the local error the controller accepts
        adds an error of that size to every step, and a linearly converging iteration
        stops right at its tolerance."""
        rtol = jnp.minimum(self.rtol, STAGE_FRACTION * rtol)
        atol = jnp.minimum(self.atol, STAGE_FRACTION * atol)
        return eqx.tree_at(lambda s: (s.rtol, s.atol), self, (rtol, atol))

    def __check_init__(self):
        if (
            not isinstance(self.max_steps, int)
            or isinstance(self.max_steps, bool)
            or (self.max_steps < 1)
        ):
            raise ValueError(f"`max_steps` must be a positive int, got {self.max_steps!r}.")
        if not isinstance(self.linear_solver, AbstractLinearSolver):
            raise TypeError(
                "`linear_solver` must be an nivpjax.AbstractLinearSolver (DenseLU, Krylov, "
                f"AutoLinear), got {self.linear_solver!r}."
            )
        for name in ("rtol", "atol"):
            value = getattr(self, name)
            if isinstance(value, jax.core.Tracer):
                continue
            real = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(
                value, (bool, np.bool_)
            )
            if not (real and math.isfinite(value) and value >= 0):
                raise ValueError(f"`{name}` must be finite and non-negative, got {value!r}.")

    @abc.abstractmethod
    def _iterate(self, residual: Residual, project: Project, rho, y0, rtol, atol):
        """Return `(y, (iterations, history, linear_iterations))` with float
        diagnostics."""

    def returned_point(self, residual: Residual, project: Project, rho, y):
        r"""The value `solve` returns for the iterate `y` (no gradient): the projection
        $P(y - \rho R(y))$ on the components it moves, `y` elsewhere. A linearisation at
        the iterate that reads the branch of a switch (`Model.solve_stage`) reads it
        there, where the returned value lies: the two differ by the solver's tolerance,
        and a velocity within it of a reversal could lie on one side for the one and on
        the other side for the other."""
        y = lax.stop_gradient(y)
        rho = jnp.broadcast_to(jnp.asarray(rho, y.dtype), y.shape)
        return lax.stop_gradient(_returned(project, rho, y, y - rho * residual(y))[0])

    def solve(
        self,
        residual: Residual,
        project: Project,
        rho,
        y0,
        tangent: tuple[Residual, Project] | None = None,
    ) -> NonlinearSolution:
        """Solve $y = P(y - \\rho R(y); y)$ from the initial guess `y0`.

        **Arguments:**

        - `residual`: $R(y)$, the stage's implicit residual (per unit time).
        - `project`: $P(z; y, \\rho)$, the projector evaluated at the iterate `y` with the
          scaling `rho` actually used to form `z` (proximal maps need it).
        - `rho`: positive scaling, a scalar or one value per component.
        - `y0`: the initial guess.
        - `tangent`: `(residual, project)` as the implicit function theorem linearises
          the stage at its solution: equal to the first two in value, they may pick
          another element of the generalised Jacobian at a kink (and cost work the
          iteration does not need); the first two if `None`. The components the
          projector moves are returned as `project`'s projection of
          $y - \\rho R_{\\text{tangent}}(y)$, so they carry `project`'s element on top
          of the solution's derivative.
        """
        y0 = jnp.asarray(y0)
        rho = jnp.broadcast_to(jnp.asarray(rho, y0.dtype), y0.shape)
        rtol, atol = effective_tolerances(self.rtol, self.atol, y0.dtype)
        residual_t, project_t = (residual, project) if tangent is None else tangent
        G = natural_map(residual_t, project_t, rho)

        def _solve(_, guess):
            # Closes over the problem: custom_root ignores tangents of `_solve`'s constants,
            # so the iteration itself is never differentiated.
            return self._iterate(residual, project, rho, guess, rtol, atol)

        linear = self.linear_solver.resolve(y0.shape[0])
        y, (iterations, history, linear_iterations) = lax.custom_root(
            G, y0, _solve, linear.tangent_solve, has_aux=True
        )
        # On components the projector moves, return the projected point P(y - rho R(y)):
        # it lies in the set (exactly, up to the projection's rounding on curved
        # boundaries; the iterate only to tolerance), within |G(y)| of y,
        # with the same implicit derivative (G vanishes along the solution). So do
        # components where the iterate itself lies outside the set (P(y) != y), which
        # happens when the solve stopped unconverged with z inside the set. Free
        # components, and constrained ones whose iterate is in its set, keep the iterate,
        # which satisfies its own equations more exactly.
        # The tangent residual equals the plain one in value: only its derivative is
        # needed here, and a solve that is not differentiated skips it.
        if tangent is None:
            z = y - rho * residual(y)
        else:
            z = y - rho * (residual(y) + tangent_only(lambda v: residual_t(v) - residual(v), y))
        value, p = _returned(project, rho, y, z)
        G_y = y - p
        y_nd = lax.stop_gradient(y)
        G_final = lax.stop_gradient(G_y)
        norm = jnp.max(jnp.abs(G_final), initial=0.0)
        # The round-off floor: z's, and that of rho R's terms (`residual_scale`).
        floor = jnp.abs(lax.stop_gradient(z)) + rho * residual_scale(residual, y_nd)
        converged = scaled_error(G_final, y_nd, rtol, atol, floor) <= 1
        finite = jnp.all(jnp.isfinite(y_nd)) & jnp.isfinite(norm)
        result = RESULTS.where(
            converged & finite,
            RESULTS.successful,
            RESULTS.where(finite, RESULTS.nonlinear_max_steps_reached, RESULTS.nonfinite),
        )
        return NonlinearSolution(
            value=value,
            iterations=iterations.astype(jnp.int32),
            residual_norm=norm,
            result=result,
            history=history,
            linear_iterations=linear_iterations.astype(jnp.int32),
        )


def _returned(project: Project, rho, y, z):
    # The value returned for the iterate `y` and `z = y - rho R(y)`, and P(z).
    p = project(z, y, rho)
    outside = project(y, y, rho) != y
    return jnp.where(lax.stop_gradient((p != z) | outside), p, y), p


def init_history(max_steps, dtype, first):
    h = jnp.full((max_steps + 1,), jnp.nan, dtype)
    return h.at[0].set(first)
