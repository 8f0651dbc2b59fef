"""The assembled problem: vector field, projector, descriptor matrix, algebraic rows."""

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from . import _held, _linalg
from ._projector import AbstractProjector, ProjectionContext
from ._projector.located import locate_selections
from ._results import RESULTS
from ._tangent import tangent_only


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
    - `has_algebraic`: whether any row is algebraic (static).
    - `has_selections`: whether any algebraic row is a selection row (static; see
      `selection_rows`).
    - `has_held_rows`: whether a set can hold a differential row at a face (static; not a
      proximal map's rows, nor a contact's: see `nivpjax._stepper.departure`).
    - `unit_mass`: whether $A$ is the identity on the differential rows and zero on the
      algebraic ones (static; `Model.build` reads it off a concrete $A$). Products with
      $A$ and solves with its differential block are then masks.
    """

    vector_field: Callable[[Any, Any, Any], Any]
    projector: AbstractProjector
    mass_matrix: Float[Array, "n n"] | None
    algebraic: Bool[Array, " n"]
    tau: Float[Array, " n"] | float = 1.0
    equation_rows: Bool[Array, " n"] | None = None
    has_algebraic: bool = eqx.field(static=True, default=False)
    unit_mass: bool = eqx.field(static=True, default=False)
    has_selections: bool = eqx.field(static=True, default=False)
    has_held_rows: bool = eqx.field(static=True, default=False)

    @classmethod
    def build(cls, vector_field, projector, mass_matrix, algebraic, **kwargs) -> "Model":
        """A model whose static flags are read off the concrete `algebraic` rows and
        `mass_matrix` (a NumPy array, or `None` for the identity; stored as a JAX array
        of the same dtype), with interval and orthant blocks on selection rows
        event-located on their residual (`locate_selections`)."""
        algebraic = np.asarray(algebraic, bool)
        equation_rows = kwargs.get("equation_rows")
        selections = algebraic
        if equation_rows is not None:
            selections = algebraic & ~np.asarray(equation_rows, bool)
        projector = locate_selections(projector, vector_field, selections)
        unit = True
        if mass_matrix is not None:
            unit = bool(np.array_equal(mass_matrix, np.diag((~algebraic).astype(float))))
            mass_matrix = jnp.asarray(mass_matrix)
        return cls(
            vector_field=vector_field,
            projector=projector,
            mass_matrix=mass_matrix,
            algebraic=algebraic,
            has_algebraic=bool(algebraic.any()),
            unit_mass=unit,
            has_selections=bool(selections.any()),
            has_held_rows=_has_held_rows(projector, algebraic),
            **kwargs,
        )

    def f(self, t, y, args):
        return jnp.asarray(self.vector_field(t, y, args), y.dtype)

    def mass_times(self, v):
        if self.mass_matrix is None:
            return v
        if self.unit_mass:
            return jnp.where(self.algebraic, 0.0, v)
        return self.mass_matrix @ v

    def _rate(self, t, y, args):
        """$y'$ on differential rows (zero on algebraic rows): $A_{dd}^{-1} f_d$."""
        return self.to_state(self.f(t, y, args))

    def to_state(self, v):
        """$A_{dd}^{-1} v_d$ on differential rows, zero on algebraic rows: turns a vector in
        the units of $f$ (a rate, a reaction, an error of $A y$) into state units."""
        v = jnp.where(self.algebraic, 0.0, v)
        if self.mass_matrix is None or self.unit_mass:
            return v
        A = self.mass_matrix + jnp.diag(self.algebraic.astype(v.dtype))
        return _linalg.solve_or_nan(A, v)

    def reaction(self, multipliers):
        """The constraint reaction of a stage (its residual, per unit time, in the units of
        $f$) on differential rows; zero on algebraic rows, whose residual is an equation."""
        return jnp.where(self.algebraic, 0.0, multipliers)

    @property
    def selection_rows(self):
        """The algebraic rows that are not equation rows: multipliers whose value is a
        selection of a set-valued law (relay, friction, contact), which a stage may set
        anywhere in its set. Equation rows are functions of the time and the differential
        states (index 1): their value at the start of a step is the right one there."""
        if self.equation_rows is None:
            return self.algebraic
        return self.algebraic & ~jnp.asarray(self.equation_rows)

    @property
    def has_impulses(self) -> bool:
        """Whether the projector can apply impulses (static)."""
        return self.projector.has_event_time

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

        Switch sensitivity (`event_sensitivity`): a stage whose solution lies on another
        branch of a switch than its start (a slip reversal, a relay crossing its surface:
        `AbstractProjector.switch_shift`) moves its base point by the saltation term
        $(f^- - f^+)\,d\tau$, zero in value; the branch is read from the iterate, so the
        implicit function theorem carries the term through the stage's own sensitivity.
        A stage ending on a switching surface that the flow crosses (a transient stick or
        landing) moves its result instead.

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

        switch = None
        if event_sensitivity and self.projector.has_switch_shift:
            switch = self._switch_shifts(t_end - h_eff, y_prev, t_end, args)

        weight, start = self._weighed_start(theta, t_end - h_eff, h_eff, y_prev, f_explicit, args)
        if start is not None:
            f_explicit = f_explicit + start
        explicit = self._explicit_rate(t_end, h_eff, y_prev, f_explicit, args, event_sensitivity)

        def reaction(y, base, tangent=False):
            fy = self.f(t_end, y, args)
            diff = self.mass_times(y - base) / h_eff - theta * fy
            if f_explicit is not None:
                diff = diff - (1 - theta) * (explicit(y) if tangent else f_explicit)
            if weight is not None:
                diff = diff / weight
            return jnp.where(alg, -fy, diff)

        def residual(y, tangent=False):
            # The switch's base shift is zero in value and in its derivative with respect
            # to the iterate (it scales d tau, which depends on the stage start only): the
            # iteration does without it, the linearisation at the solution carries it. Its
            # branch is read at the value the solver returns (as the end shift's is), not
            # at the iterate, which may lie on the other side of a switch it landed on.
            if switch is None or not tangent:
                return reaction(y, y_base, tangent)
            landed = solver.returned_point(reaction_at_base, project, rho, y)
            return reaction(y, y_base + switch(landed)[0], tangent)

        def reaction_at_base(y):
            return reaction(y, y_base)

        alg_rho = self.tau / h_eff
        if self.equation_rows is not None:
            alg_rho = jnp.where(self.equation_rows, self.tau, alg_rho)
        rho = jnp.where(alg, alg_rho, h_eff).astype(guess.dtype)

        start_rate = self._start_rate(t_end, h_eff, y_prev, args)

        def project(z, y, rho_used, tangent=False):
            ctx = ProjectionContext(
                t=t_end,
                h=h_eff,
                y_prev=y_prev,
                y_iter=y,
                rho=rho_used,
                args=args,
                start_rate=start_rate,
                tangent=tangent,
            )
            return self.projector(z, ctx)

        tangent = None
        if switch is not None or self.projector.has_kinks:
            tangent = (
                lambda y: residual(y, tangent=True),
                lambda z, y, rho_used: project(z, y, rho_used, tangent=True),
            )
        sol = solver.solve(residual, project, rho, guess, tangent)
        multipliers = reaction(sol.value, y_base)
        if weight is not None:
            # The reaction the stage applied, averaged over it, as without weighing.
            multipliers = weight * multipliers + (1 - weight) * start
        if delta is not None:
            value = sol.value - self._rate(t_end, sol.value, args) * delta
            sol = eqx.tree_at(lambda s: s.value, sol, value)
        if switch is not None:

            def correction(y):
                # Multipliers at a switch take no derivative: a relay's selection at a
                # vertex has none, and a transient landing's is an artefact of the step
                # (its value makes the state land), which an explicit stage after it must
                # not read. Zero in value, like the end shift.
                _, end, found = switch(y)
                return end - jnp.where(alg & found, y - jax.lax.stop_gradient(y), 0.0)

            value = sol.value + tangent_only(correction, sol.value)
            sol = eqx.tree_at(lambda s: s.value, sol, value)
        return sol, multipliers

    def _weighed_start(self, theta, t0, h, y0, f_explicit, args):
        r"""`(weight, start)` for a stage of the theta family from `(t0, y0)` of length `h`:
        on the rows whose reaction the projector weighs (`weighed_rows`: friction applied
        as a proximal map), the stage solves

        $$ A(y - y_0)/h = \theta\,(f(t_1, y) + r_1) + (1 - \theta)\,(f_0 + r_0), $$

        with $r_1$ the reaction of the stage's end (its residual divided by `weight` =
        $\theta$ there, 1 elsewhere: the law's bound scaled by $\theta$) and $r_0$ =
        `start` the reaction at the start, added to the explicit rate. Applied whole at
        the end ($h r_1$), a reaction that changes along a phase (a slip-weakening bound,
        the direction of a disk friction force) is integrated at first order, and the
        second-order estimates do not see it (measured: a driven stick-slip slider 2.5e-3
        off at rtol 1e-5 with Bathe, its error growing through each slip phase).

        $r_0$ is the law's reaction at $(t_0, y_0)$: the one-sided derivative
        $\frac{d}{ds} P_s(y_0 + s f_0) - f_0$ at $s \to 0^+$, $P_s$ the projector with
        weight $s$ (per row of a diagonal $A$; a JVP at $s = 10^{-6} h$, no
        difference quotient to lose digits): $-c\,v_0/|v_0|$ in slip, the bound read at the
        start; the holding force $-f_0$, clipped to the bound, in stick. A backward Euler
        step's reaction over $h$ would point along the predicted velocity instead, an
        $O(h)$ error in the direction of a disk friction force (order 1.00 again on the
        disk, measured). `(None, None)` for backward Euler's stages and models without such
        rows (`theta` may be traced: Bathe's stages share one body)."""
        if f_explicit is None or not self.has_weighed:
            return None, None
        if isinstance(theta, float) and theta == 1.0:
            return None, None
        weight = jnp.where(self.weighed, theta, 1.0).astype(y0.dtype)
        return weight, self.law_reaction(t0, h, y0, f_explicit, args)

    @property
    def weighed(self):
        """The differential rows whose reaction a stage weighs like $f$ (static mask, see
        `AbstractProjector.weighed_rows`)."""
        n = self.algebraic.shape[0]
        return jnp.asarray(self.projector.weighed_rows(n)) & ~self.algebraic

    @property
    def has_weighed(self) -> bool:
        return bool(self.projector.weighed_rows(self.algebraic.shape[0]).any())

    def law_reaction(self, t, h, y, f, args):
        r"""The reaction (units of $f$) of the weighed rows' law at `(t, y)` under the
        smooth rate `f`, zero on other rows; `h` only sets the JVP's point $10^{-6} h$
        (see `_weighed_start`), or $\sqrt\varepsilon\,h$ where that is larger (float32:
        $3.5 \cdot 10^{-4} h$; at $10^{-6} h$ the point rounds to $y$ and a resting
        contact reads as open). Not from the rate's size, as `projected_rate`'s point: a
        friction law whose velocity comes to rest has a kink within a point moved out
        that far (the interval block's stop then stalled the trapezoidal rule)."""
        s = jnp.maximum(1e-6, jnp.sqrt(jnp.finfo(y.dtype).eps)) * jnp.where(h > 0, h, 1.0)
        return jnp.where(self.weighed, self._prox_rate(t, s, y, f, args) - f, 0.0)

    def _prox_rate(self, t, s, y, f, args):
        r"""$\frac{d}{ds} P_s(y + s f)$ at a small $s > 0$ ($s \to 0^+$), $P_s$ the projector
        with weight $s$: the rate the projector lets a state at `y` take under the smooth
        rate `f` (units of $f$): `f` where no set holds a row, its tangential part at a
        face, the law's reaction added on a proximal map's rows. A JVP at a small positive
        $s$, not a difference quotient: no digits lost, and the projectors' kink rules at
        $s = 0$ (the identity on the set) never apply."""
        # The stage's fixed point y = P(y - rho R) takes R in the units of f: at s -> 0 the
        # point projected is y + s f (per row of a diagonal A), not y + s A^-1 f.

        # Contacts read the state's rate to tell a persistent contact (see `law`).
        start_rate = jax.lax.stop_gradient(self.to_state(f)) if self.has_impulses else None

        def prox(s):
            z = y + s * f
            ctx = ProjectionContext(
                t=t,
                h=s,
                y_prev=y,
                y_iter=z,
                rho=jnp.full_like(y, s),
                args=args,
                start_rate=start_rate,
                law=True,
            )
            return self.projector(z, ctx)

        return jax.jvp(prox, (s,), (jnp.ones_like(s),))[1]

    @property
    def rated_rows(self) -> np.ndarray:
        """The rows a projector moves whose rate at a point is its projected one
        (`projected_rate`; a static NumPy mask, algebraic rows included): every row the
        projector acts on, none with impulses (a contact's velocities jump at impacts
        inside a step, which one rate per end does not describe)."""
        n = self.algebraic.shape[0]
        if self.has_impulses:
            return np.zeros(n, bool)
        return np.asarray(self.projector.acts_on(n), bool)

    @property
    def held_rows(self):
        """The differential rows a set can hold at a face (a mask): the `rated_rows` that
        are neither algebraic nor a proximal map's (`weighed`). Empty unless
        `has_held_rows`."""
        return jnp.asarray(self.rated_rows) & ~self.algebraic & ~self.weighed

    def projected_rate(self, t, h, y, f, args):
        """`(rate, held)` at `(t, y)` under the vector field's value `f` there: the rate
        (state units) the state takes from there, `f` projected (`_prox_rate`) on the
        differential `rated_rows` (zero normal motion where a set holds a row at a face, a
        proximal map's reaction added: friction), and the rows where that differs from
        `f` (held at a face, or a reaction acting). `h` only sets the JVP's point:
        $s = 10^{-6} h$, or more (up to $10^{-2} h$) where $y + s f$ would round to $y$
        (float32: a state at a face would then read as inside the set, free)."""
        if not self.rated_rows.any():
            return self.to_state(f), jnp.zeros(y.shape, bool)
        moved, rows = self._moved_rate(t, h, y, f, args, self.rated_rows)
        return self.to_state(moved), rows & (moved != f)

    def _moved_rate(self, t, h, y, f, args, rows):
        # `f` projected on the differential rows of the mask `rows` (units of f), and those
        # rows.
        rows = jnp.asarray(rows) & ~self.algebraic
        f_rows = jnp.where(rows, f, 0.0)
        finfo = jnp.finfo(y.dtype)
        speed = jnp.max(jnp.abs(f_rows)) / (1 + jnp.max(jnp.abs(y)))
        h = jnp.where(h > 0, h, 1.0)
        s = jnp.clip(64 * finfo.eps / jnp.maximum(speed, finfo.tiny), 1e-6 * h, 1e-2 * h)
        return jnp.where(rows, self._prox_rate(t, s, y, f_rows, args), f), rows

    def reaction_at(self, t, h, y, args):
        r"""The constraint reaction at the state `(t, y)` (units of $f$; a row of the
        `multipliers` buffer's instantaneous counterpart), inside its set:

        - on the differential rows a projector acts on, the projected rate minus the
          vector field (`_moved_rate`): zero where the row is free, $-f$ on the normal
          rows where a set holds the state at a face (exactly: the projection's derivative
          there is 0), the law's reaction on a proximal map's rows (friction:
          $-c \operatorname{sign} v$ in slip, the holding force in stick), put into its
          bound (`project_reaction`). On a contact's velocity rows: zero off contact, the
          resting force where the contact holds the body (the one-sided derivative of its
          impulse, $\ge 0$: a resting ball's $g$); an impact is an impulse, not a force,
          and has none;
        - on algebraic rows, the row's residual $-f(t, y)$, as in the buffer;
        - zero on the other rows.

        `h` only sets the JVP's point (see `projected_rate`)."""
        f = self.f(t, y, args)
        out = jnp.where(self.algebraic, -f, 0.0)
        acts = np.asarray(self.projector.acts_on(y.shape[0]), bool)
        if not acts.any():
            return out
        moved, rows = self._moved_rate(t, h, y, f, args, acts)
        reaction = jnp.where(rows, moved - f, out)
        if self.has_weighed:
            reaction = self.project_reaction(t, y, reaction, args)
        return reaction

    def project_reaction(self, t, y, r, args):
        r"""`r` with the rows of a proximal map (`weighed`: friction) put into the map's
        reaction set at `(t, y)` by the projector itself, through Moreau's decomposition
        at unit weight: with $P$ the map $P(z) = z - \operatorname{proj}_C(z)$ (friction:
        soft thresholding by the bound $c$, $C$ its interval or disk),
        $\operatorname{proj}_C(r) = r - P(r)$. On an interval this is exact for a value
        within a factor 2 of the bound (Sterbenz's lemma: $P(r) = r \mp c$ without
        rounding), as a reaction computed as $(F - c) - F$ is: it comes back as $\mp c$ bit
        for bit, where it could lie half an ulp of $F$ past the bound."""
        ctx = ProjectionContext(
            t=t, h=jnp.ones_like(t), y_prev=y, y_iter=y, rho=jnp.ones_like(y), args=args
        )
        moreau = r - self.projector(jnp.where(self.weighed, r, y), ctx)
        return jnp.where(self.weighed, moreau, r)

    def project_rows(self, t, h, y, rows, args):
        """`y` with the rows `rows` (a boolean mask) replaced by the projector's value at
        `y` (weight `h`): an interpolated state put back into its sets."""
        ctx = ProjectionContext(t=t, h=h, y_prev=y, y_iter=y, rho=jnp.full_like(y, h), args=args)
        return jnp.where(rows, self.projector(y, ctx), y)

    def law_reaction_linearized(self, t, h, y, args):
        r"""`(r, along)`: `law_reaction` at `(t, y)` under the vector field there, and
        `along(rate)`, its derivative along a state rate,
        $\partial_t r + \partial_y r \cdot$ `rate` (one linearisation: the reaction is
        needed for the rate before its derivative along it)."""

        def law(tt, yy):
            return self.law_reaction(tt, h, yy, self.f(tt, yy, args), args)

        r, linear = jax.linearize(law, t, y)
        return r, lambda rate: linear(jnp.ones_like(t), rate)

    def _explicit_rate(self, t_end, h, y_prev, f_explicit, args, event_sensitivity):
        # The explicit start rate of a stage as a function of its iterate, for the stage's
        # linearisation: `f_explicit` in value; where a kink was crossed early in the stage
        # (`early_kinks`), its multipliers' derivatives are the iterate's (the branch the
        # flow takes from just after the start) instead of the start's own (the branch it
        # left: a diode's current tracking the source, as it did before turning off).
        if f_explicit is None or not (event_sensitivity and self.projector.has_kinks):
            return lambda y: f_explicit
        sg = jax.lax.stop_gradient

        def explicit(y):
            early = self.projector.early_kinks(self._context(t_end, h, y_prev, y, args))
            move = jnp.where(early, (y - sg(y)) - (y_prev - sg(y_prev)), 0.0)
            field = lambda u: self.f(t_end - h, u, args)  # noqa: E731
            return f_explicit + jax.jvp(field, (sg(y_prev),), (move,))[1]

        return explicit

    def apply_impacts(self, t0, h, y0, args):
        r"""The state after the impulses the projector applies at the start of a step of
        size `h` (see `AbstractProjector.impact`): impacts are resolved first, and the
        step's stages integrate the smooth flow from there.

        Event sensitivity, as in `solve_stage`: the impact is applied at $t_0$ although
        the flow meets the contact $\tau$ (`event_time`) later; with
        $\delta = \tau - \text{stop\_gradient}(\tau)$, zero in value, the state moves along
        the pre-impact flow by $\delta$ before the impact map and back along the
        post-impact flow after it, which carries the saltation term $(D I\,f^- - f^+)\,d\tau$
        into derivatives.

        Returns `(y_plus, timing_error)`: the second is the local error of applying the
        impact at $t_0$ instead of $t_0 + \tau$, $\tau\,(\dot y^+ - D I\,\dot y^-)$ to
        first order (zero without an impact), which the steppers add to their error estimate: a
        step that starts well before a contact closes is rejected, and the impact is
        located to the tolerance."""
        if not self.has_impulses:
            return y0, jnp.zeros_like(y0)
        y_plus, tau, saltation = self._impact(t0, h, y0, args)
        # Only an early impact (the contact closes later) can be fixed by a shorter step;
        # a late one (the previous step ended penetrated) was charged by its violation.
        return y_plus, jnp.maximum(tau, 0.0) * saltation

    def _impact(self, t0, h, y0, args):
        # The impacts at the start of a stage from (t0, y0) of length h: the state after
        # them (with the event sensitivity of `apply_impacts`), the time tau at which the
        # flow meets the contact (zero without an impact, negative when y0 is already
        # penetrated; no gradient) and the saltation term f+ - DI f- (no gradient): the
        # local error of applying the impact tau early is tau (f+ - DI f-) to first order.
        t1 = t0 + h
        ctx0 = self._context(t1, h, y0, y0, args)
        tau, found = self.projector.event_time(ctx0)
        delta = jnp.where(found, tau - jax.lax.stop_gradient(tau), 0.0)
        rate_minus = self._rate(t0, y0, args)
        y_shift = y0 + rate_minus * delta
        # The impact and its derivative along the flow, DI f-, in one evaluation.
        sg = jax.lax.stop_gradient
        impact_of = lambda y: self.projector.impact(self._context(t1, h, y, y, args))  # noqa: E731
        y_plus, carried = jax.jvp(impact_of, (y_shift,), (sg(rate_minus),))
        rate_plus = self._rate(t0, y_plus, args)
        # The saltation term: the flow after the impact from the impact of the flow; the
        # impact map's own derivative matters (a velocity-level law reflects the
        # approaching acceleration too: (1 + e) g tau on a bouncing ball).
        tau_value = jnp.where(found, sg(tau), 0.0)
        return y_plus - rate_plus * delta, tau_value, sg(rate_plus - carried)

    def stage_impact_error(self, t0, h, y0, change, args):
        r"""The local error of a stage from `(t0, y0)` of length `h` that applies an impact
        at its start (a later stage of a multistage step that starts at, or just before, a
        contact closing), given `change`, the state change its reaction made (its
        multipliers times `h`, in state units). Two parts:

        - the timing, $\tau\,(f^+ - D I\,f^-)$, $\tau$ the time from the stage start to
          the contact's closing: negative when the stage starts penetrated (the impact
          comes late), zero for a gap closed to round-off;
        - what the reaction did beyond the impact's jump $I(y_0) - y_0$: a velocity-level
          contact enforces $u_1 \ge -e\,u^-$ at the stage's end, so after the impact it
          holds the body against the flow for the rest of the stage ($h\,|a|$ on its
          normal velocity, $a$ the normal acceleration), where the body should fly.

        Both are the computed state minus the exact one, to first order, so they add with
        their signs (a late impact and the holding both leave a bouncing ball too fast).
        Zero without an impact."""
        if not self.has_impulses:
            return jnp.zeros_like(y0)
        y_plus, tau, saltation = self._impact(t0, h, y0, args)
        held = jax.lax.stop_gradient(change - (y_plus - y0))
        return tau * saltation + held

    def _switch_shifts(self, t_start, y_start, t_end, args):
        # The base-point and end-point shifts of a switching stage as functions of the
        # stage iterate: the projectors' shifts, multiplier jumps mapped through the vector
        # field.
        rate0 = self._rate(t_start, y_start, args)

        def rate_at(y):
            return self._rate(t_start, y, args)

        def through_field(shift):
            if not self.has_algebraic:
                return shift
            on_alg = jnp.where(self.algebraic, shift, 0.0)
            moved = self._rate(t_start, y_start + on_alg, args) - rate0
            return jnp.where(self.algebraic, 0.0, shift) + moved

        def shifts(y):
            h = t_end - t_start
            ctx = self._context(t_end, h, y_start, y, args, rate=rate0, rate_at=rate_at)
            base, end, found = self.projector.switch_shift(ctx)
            return through_field(base), through_field(end), found

        return shifts

    def switch_jump(self, t0, y0, t1, y1, args):
        r"""The saltation term $(f^- - f^+)\,\delta\tau$ (zero in value) of a switch
        between `(t0, y0)` and `(t1, y1)`, zero if none: a multistage step moves its
        earlier points by it, so that they lie on the post-switch branch as the later ones
        do (to first order)."""
        if not self.projector.has_switch_shift:
            return jnp.zeros_like(y0)
        return tangent_only(lambda y: self._switch_shifts(t0, y0, t1, args)(y)[0], y1)

    def step_start(self, t0, h, y0, args):
        """The start of a step of size `h` as every stepper takes it: the impacts closing
        there applied (`apply_impacts`), then the right-limit selections (`start_state`).
        Returns the start state, the rate there, and the local error both charge (the
        impact's timing; a switch moved to the start, where `start_state` charges it)."""
        y0, impact_error = self.apply_impacts(t0, h, y0, args)
        y0, f0, start_error = self.start_state(t0, h, y0, args)
        return y0, f0, impact_error + start_error

    def start_state(self, t0, h, y0, args):
        """`y0` with the right-limit selections at the start of a step of size `h` (see
        `AbstractProjector.start_selection`; unchanged where the projector has none) and
        the differential rows shifted by a switch moved to the start (below), and the
        rate there (what explicit parts of stages and embedded estimates read)."""
        if self.has_selections:
            y0 = _held.held_start(self, t0, h, y0, args)
        f0 = self.f(t0, y0, args)
        if not self.projector.has_start_selection:
            return y0, f0, jnp.zeros_like(y0)
        ctx = self._context(t0 + h, h, y0, y0, args, rate_at=lambda y: self._rate(t0, y, args))
        selection, skipped = self.projector.start_selection(ctx)
        y0_start = jnp.where(self.algebraic, selection, y0)
        f0_start = self.f(t0, y0_start, args)
        jump = self.to_state(f0 - f0_start)
        # A switch moved to the start from `skipped` later: the effective start is
        # y0 + skipped (f^- - f^+), the state that the far branch's flow carries to the
        # exact one at the switch (exact for rates constant over `skipped`). In
        # derivatives it is the saltation term (f^- - f^+) d tau, which a switch inside
        # the step would carry. Charged as an error instead (before), the skip was a
        # local error fixed by the controller's margin, not by h: a Filippov spiral's
        # 20 000 switchings added up to 1.7e-5 V0 at every rtol, and at rtol 1e-8 a step
        # landing 1e-8 of its size short of a switch was rejected at every size.
        if self.has_impulses:
            # With contacts the shift stays charged as an error, carried in derivatives
            # only, as before: shifting a contact's positions in value has not been
            # measured against its gap (a shift could open or close it).
            delta = skipped - jax.lax.stop_gradient(skipped)
            error = jax.lax.stop_gradient(skipped * jump)
            return jnp.where(self.algebraic, y0_start, y0_start + jump * delta), f0_start, error
        y0_start = jnp.where(self.algebraic, y0_start, y0_start + jump * skipped)
        return y0_start, f0_start, jnp.zeros_like(y0)

    def consistent_initial_state(self, solver, t0, h, y0, args):
        r"""Consistent algebraic rows at $t_0$, and an initial state outside the admissible
        set projected onto it.

        Two stages. The first has the differential states held fixed ($\theta = 0$): it
        projects the state and solves index-1 rows (a saturation, a diode with series
        resistance) exactly at $t_0$. A multiplier that acts through the velocity (a
        contact's normal force, a friction reaction, a relay sliding on its surface) is
        not determined by the state alone: its condition at $t_0$ does not depend on it, and
        that stage leaves it at the initial guess. The second stage, a backward Euler step
        of length $h$, determines it as the reaction over $[t_0, t_0 + h]$, $O(h)$ from its
        value at $t_0$; the other algebraic rows are taken from it too (off a switching
        surface it selects what the first did). A trapezoidal step averages the reactions
        at both ends, so one inconsistent start value would ring from step to step for the
        whole run: the block on a plane with its normal force started at 0 alternated
        between $0$ and $2g$, and the trapezoidal rule took 7 281 steps at rtol 1e-6 and
        stopped the block 2e-4 off. The differential rows are the first stage's."""

        def stage(y, theta):
            # One traced stage serves both (theta = 0 at t0, then 1 at t0 + h): the
            # start-up compiles one nonlinear solve, not two.
            out = self.solve_stage(
                solver, t0 + theta * h, h, y, None, theta, y, y, args, event_sensitivity=False
            )[0]
            return out.value, out

        thetas = jnp.array([0.0, 1.0], dtype=jnp.result_type(y0))
        _, both = jax.lax.scan(stage, y0, thetas)
        init, be = (jax.tree_util.tree_map(lambda a: a[i], both) for i in (0, 1))
        y = init.value
        rows = (
            self.algebraic if self.equation_rows is None else self.algebraic & ~self.equation_rows
        )
        ok = be.result == RESULTS.successful
        return eqx.tree_at(lambda s: s.value, init, jnp.where(rows & ok, be.value, y))

    def equation_rate(self, t, y, rate, args, fallback):
        r"""The rates of the equation rows (`equation_rows`: saturations, diodes with
        series resistance) at $(t, y)$ along the flow, `fallback` on every other row.

        Equation rows are index-1: their projected equation $G(t, y) = y - P(y - \tau
        R(t, y)) = 0$ determines them from the time and the differential states, so
        differentiating it along the flow gives their rate, $G_z\,z' = -(G_t + G_x x')$,
        with $x'$ the differential rows of `rate` and $G_z$ the projector's element of the
        generalised Jacobian at $y$ (the face $y$ lies on). A secant over a step instead
        misses how the rate itself changes: a diode's current tracking its source is
        the dominant term of a trapezoidal step's error in conduction (an estimate 500x
        too small was measured on the half-wave rectifier). Where $G_z$ is singular (a
        row declared an equation that is not one), `fallback`."""
        if self.equation_rows is None:
            return fallback
        eq = jnp.asarray(self.equation_rows)
        rho = jnp.where(self.algebraic, self.tau, 1.0).astype(y.dtype)
        x_rate = jnp.where(self.algebraic, 0.0, rate)

        def G(tt, yy):
            ctx = ProjectionContext(
                t=tt,
                h=jnp.ones_like(tt),
                y_prev=yy,
                y_iter=yy,
                rho=rho,
                args=args,
                start_rate=x_rate,
            )
            r = jnp.where(self.algebraic, -self.f(tt, yy, args), 0.0)
            return jnp.where(eq, yy - self.projector(yy - rho * r, ctx), 0.0)

        _, g_dot = jax.jvp(G, (t, y), (jnp.ones_like(t), x_rate))
        J = jax.jacfwd(lambda yy: G(t, yy))(y)
        M = jnp.where(eq[:, None] & eq[None, :], J, jnp.eye(y.shape[0], dtype=y.dtype))
        z_rate = _linalg.solve_or_nan(M, -jnp.where(eq, g_dot, 0.0))
        usable = jnp.all(jnp.isfinite(z_rate))
        return jnp.where(eq & usable, z_rate, fallback)

    def _start_rate(self, t, h, y0, args):
        # The rate at the start `(t - h, y0)` of a stage ending at `t`, for projectors with
        # events (a contact's normal acceleration tells a graze from an impact); it only
        # decides active sets, so it carries no gradient.
        if not self.has_impulses:
            return None
        return jax.lax.stop_gradient(self._rate(t - h, y0, args))

    def _context(
        self,
        t,
        h,
        y0,
        y1,
        args,
        rate=None,
        rate_at=None,
        start_rate=None,
        end_rate=None,
        y_next=None,
        next_rate=None,
        tolerance=None,
        after_end=False,
        violation_scale=None,
    ):
        rho = jnp.full_like(y1, h)
        if start_rate is None:
            start_rate = self._start_rate(t, h, y0, args)
        return ProjectionContext(
            t=t,
            h=h,
            y_prev=y0,
            y_iter=y1,
            rho=rho,
            args=args,
            rate=rate,
            rate_at=rate_at,
            start_rate=start_rate,
            end_rate=end_rate,
            y_next=y_next,
            next_rate=next_rate,
            tolerance=tolerance,
            after_end=after_end,
            violation_scale=violation_scale,
        )

    def violation(self, t1, h, y0, y1, args, tolerance=None, scale=None):
        """Constraint violation at the end of a step (see `AbstractProjector.violation`).
        The context carries the vector field at the end point (`rate`), the rates of the
        differential rows at both ends (`start_rate`, `end_rate`, state units), the
        judging controller's `(rtol, atol)` (`tolerance`, or `None`) and the scale it
        charges the violation against (`scale`, `nivpjax._norms.violation_scale`)."""
        rate = self.f(t1, y1, args)
        start_rate = jax.lax.stop_gradient(self._rate(t1 - h, y0, args))
        end_rate = self.to_state(rate)
        ctx = self._context(
            t1,
            h,
            y0,
            y1,
            args,
            rate,
            start_rate=start_rate,
            end_rate=end_rate,
            tolerance=tolerance,
            violation_scale=scale,
        )
        return self.projector.violation(ctx)

    def held_exit(self, t1, h, y0, y1, args):
        """`(violation, time)` of a held phase (sliding, sticking on selection rows) that
        ended and began again inside the step, which its two ends do not show (see
        `nivpjax._held.held_exit`); `(0, inf)` without selection rows."""
        if not self.has_selections:
            zero = jnp.zeros((), y1.dtype)
            return zero, jnp.full((), jnp.inf, y1.dtype)
        rate0 = self._rate(t1 - h, y0, args)
        rate1 = self._rate(t1, y1, args)
        return _held.held_exit(self, t1, h, y0, y1, rate0, rate1, args)

    def next_event(self, t1, h, y0, y1, args, after_end=False, tolerance=None, started=False):
        """Predicted time from `t1 - h` to the first event (see
        `AbstractProjector.next_event`); with `after_end`, the first after the step's
        end that matters under the controller's `tolerance` (`ProjectionContext.after_end`:
        what a controller sizes the next step by). `started`: `y0` is already the step's
        start (`step_start`), and only events inside the step are wanted (a stepper's
        estimate), so neither the start nor the next step's start is worked out again."""
        rate = self.f(t1, y1, args)
        y0, start_rate, y_next, next_rate = self._predicting_rates(t1, h, y0, y1, args, started)
        ctx = self._context(
            t1,
            h,
            y0,
            y1,
            args,
            rate=rate,
            start_rate=start_rate,
            end_rate=self.to_state(rate),
            y_next=y_next,
            next_rate=next_rate,
            after_end=after_end,
            tolerance=tolerance,
        )
        return jax.lax.stop_gradient(self.projector.next_event(ctx))

    def _predicting_rates(self, t1, h, y0, y1, args, started=False):
        # `(y0, start_rate, y_next, next_rate)` for `next_event`, every projector (the switching
        # functions' predictions read both rates; contacts read the start's as well). The
        # start as the step takes it (`step_start`: impacts applied, and the selections a
        # switch at the start flips), whose rate the flow followed: a step starting just
        # short of a relay's switch read the rate of the branch it was leaving, and
        # predicted no switch of the other relay the far branch drives to its surface
        # (a Filippov spiral: five attempts per quadrant, at most one is needed). The
        # next step's start likewise (`start_state` at the end) for the prediction ahead,
        # which a stepper (`started`: events inside its step only) does not read.
        if started or not self.projector.has_start_selection:
            y0 = jax.lax.stop_gradient(self.apply_impacts(t1 - h, h, y0, args)[0])
            return y0, self._rate(t1 - h, y0, args), None, None
        y0, f0, _ = jax.lax.stop_gradient(self.step_start(t1 - h, h, y0, args))
        y_next, f1, _ = jax.lax.stop_gradient(self.start_state(t1, h, y1, args))
        return y0, self.to_state(f0), y_next, self.to_state(f1)

    @property
    def has_arrests(self) -> bool:
        return self.projector.has_arrests

    def arrest_error(self, t1, h, y0, y1, f0, f1, args):
        """`(arrested, error)`, full state: the rows that came to rest inside the step from
        `y0` to `y1` and the local error of their end values (see
        `AbstractProjector.arrest_error`), for a stepper's error estimate; `f0`, `f1`: the
        vector field at the two ends (a stepper has them: a large model's field is its
        cost)."""
        rate0, rate1 = self.to_state(f0), self.to_state(f1)
        ctx = self._context(t1, h, y0, y1, args, start_rate=rate0, end_rate=rate1)
        return self.projector.arrest_error(ctx)

    def initial_violation(self, t0, h, y0, args):
        """Violation of the initial state no stage can restore (see
        `AbstractProjector.initial_violation`)."""
        return self.projector.initial_violation(self._context(t0, h, y0, y0, args))

    def impulsive(self, t1, h, y0, y1, args):
        """Whether a stage from `y0` to `y1` contained an impulse."""
        return self.projector.impulsive(self._context(t1, h, y0, y1, args))

    def switched(self, t1, h, y0, y1, args):
        """Whether a stage from `y0` to `y1` changed the face of a set-valued law (a relay
        leaving a bound, friction sticking or slipping, a diode switching, a contact
        opening or closing), see `AbstractProjector.switched`."""
        return self.projector.switched(self._context(t1, h, y0, y1, args))


def _has_held_rows(projector, algebraic) -> bool:
    # Differential rows a set can hold at a face (not a proximal map's rows, not a
    # contact's, whose velocities jump): see `nivpjax._stepper.departure`.
    n = algebraic.shape[0]
    if projector.has_event_time:
        return False
    rows = np.asarray(projector.acts_on(n), bool) & ~algebraic
    return bool((rows & ~np.asarray(projector.weighed_rows(n), bool)).any())
