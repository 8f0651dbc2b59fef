"""The assembled problem: vector field, projector, descriptor matrix, algebraic rows."""

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._projector import AbstractProjector, ProjectionContext


class Model(eqx.Module):
    r"""$A y' = f(t, y, \text{args})$ with the set-valued rule encoded by `projector`.

    - `vector_field`: $f(t, y, \text{args})$, diffrax's convention.
    - `projector`: the projector $P_K$ (identity for a smooth problem).
    - `mass_matrix`: the constant descriptor matrix $A$, or `None` for the identity.
    - `algebraic`: rows of $A$ that are identically zero (algebraic equations, multipliers,
      switching selections). They are collocated at the end of each stage, scaled by
      `tau / h` in the projection (see below) and left out of the error norm by default.
    - `tau`: scaling of algebraic rows (scalar or per row): $\rho_i = \tau_i / h$ there and
      $\rho_i = h$ on differential rows. A multiplier that enters its constraint with weight
      $h$ (friction, relay and contact multipliers) is then scaled $O(1)$.
    - `equation_rows`: algebraic rows scaled $\rho_i = \tau_i$ instead (no $1/h$): algebraic
      equations with $O(1)$ sensitivity to their own unknowns (saturations, diodes with
      series resistance). Only the VI method's convergence depends on this; Newton does not.
    """

    vector_field: Callable[[Any, Any, Any], Any]
    projector: AbstractProjector
    mass_matrix: Float[Array, "n n"] | None
    algebraic: Bool[Array, " n"]
    tau: Float[Array, " n"] | float = 1.0
    equation_rows: Bool[Array, " n"] | None = None
    has_algebraic: bool = eqx.field(static=True, default=False)

    def f(self, t, y, args):
        return jnp.asarray(self.vector_field(t, y, args), y.dtype)

    def mass_times(self, v):
        return v if self.mass_matrix is None else self.mass_matrix @ v

    def _rate(self, t, y, args):
        """$y'$ on differential rows (zero on algebraic rows): $A_{dd}^{-1} f_d$."""
        f = jnp.where(self.algebraic, 0.0, self.f(t, y, args))
        if self.mass_matrix is None:
            return f
        A = self.mass_matrix + jnp.diag(self.algebraic.astype(y.dtype))
        return jnp.linalg.solve(A, f)

    def solve_stage(
        self,
        solver,
        t_end,
        h_eff,
        y_base,
        f_explicit,
        theta,
        y_prev,
        guess,
        args,
        event_sensitivity=True,
    ):
        r"""Solve one one-leg stage: find $y$ with, on differential rows,
        $A(y - y_b)/h_e = \theta f(t_e, y) + (1-\theta) f_x$ ($y_b$ = `y_base`,
        $h_e$ = `h_eff`, $t_e$ = `t_end`, $f_x$ = `f_explicit`), on algebraic rows
        $0 = f(t_e, y)$, subject to the projector.

        Event sensitivity (`event_sensitivity`): a stage containing an event the projector
        reports (`event_time`: an impact) applies it as if the flow met the contact at the
        stage start, with the stage's times fixed, so plain derivatives miss how the event
        time $\tau$ moves with the state and parameters (the saltation term
        $(D R\, f^- - f^+)\,d\tau$, $R$ the impact map). With
        $\delta = \tau - \text{stop\_gradient}(\tau)$, zero in value so the solution is
        unchanged, the stage start moves along the pre-event flow by $\delta$ (the stage's
        impact map then contributes $D R\, f^- \delta$) and the stage result moves back
        along the post-event flow by $\delta$ ($-f^+ \delta$).

        Returns the nonlinear solution and the stage residual at the solution (the
        constraint reaction per unit time: forces, contact impulses divided by $h$)."""
        alg = self.algebraic
        delta = None
        if event_sensitivity and self.projector.has_event_time:
            ctx0 = self._context(t_end, h_eff, y_prev, y_prev, args)
            tau, found = self.projector.event_time(ctx0)
            delta = jnp.where(found, tau - jax.lax.stop_gradient(tau), 0.0)
            rate0 = self._rate(t_end - h_eff, y_prev, args)
            y_base = y_base + rate0 * delta
            y_prev = y_prev + rate0 * delta

        def residual(y):
            fy = self.f(t_end, y, args)
            diff = self.mass_times(y - y_base) / h_eff - theta * fy
            if f_explicit is not None:
                diff = diff - (1 - theta) * f_explicit
            return jnp.where(alg, -fy, diff)

        alg_rho = self.tau / h_eff
        if self.equation_rows is not None:
            alg_rho = jnp.where(self.equation_rows, self.tau, alg_rho)
        rho = jnp.where(alg, alg_rho, h_eff).astype(guess.dtype)

        def project(z, y, rho_used):
            ctx = ProjectionContext(
                t=t_end, h=h_eff, y_prev=y_prev, y_iter=y, rho=rho_used, args=args
            )
            return self.projector(z, ctx)

        sol = solver.solve(residual, project, rho, guess)
        multipliers = residual(sol.value)
        if delta is not None:
            value = sol.value - self._rate(t_end, sol.value, args) * delta
            sol = eqx.tree_at(lambda s: s.value, sol, value)
        return sol, multipliers

    def consistent_initial_state(self, solver, t0, h, y0, args):
        r"""Solve the algebraic rows and the projection at $t_0$ with the differential
        states held fixed (a stage with $\theta = 0$): multipliers get their consistent
        values (a relay selection, a diode current) before the first step uses them, and an
        initial state outside the admissible set is projected onto it."""
        return self.solve_stage(
            solver, t0, h, y0, None, 0.0, y0, y0, args, event_sensitivity=False
        )[0]

    def _context(self, t, h, y0, y1, args, rate=None):
        rho = jnp.full_like(y1, h)
        return ProjectionContext(t=t, h=h, y_prev=y0, y_iter=y1, rho=rho, args=args, rate=rate)

    def violation(self, t1, h, y0, y1, args):
        """Constraint violation at the end of a step (see `AbstractProjector.violation`).
        The context carries the vector field at the end point (`rate`)."""
        ctx = self._context(t1, h, y0, y1, args, rate=self.f(t1, y1, args))
        return self.projector.violation(ctx)

    def initial_violation(self, t0, h, y0, args):
        """Violation of the initial state no stage can restore (see
        `AbstractProjector.initial_violation`)."""
        return self.projector.initial_violation(self._context(t0, h, y0, y0, args))

    def impulsive(self, t1, h, y0, y1, args):
        """Whether a stage from `y0` to `y1` contained an impulse."""
        return self.projector.impulsive(self._context(t1, h, y0, y1, args))
