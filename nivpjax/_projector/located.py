"""Event location on a switching surface for any projector."""

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _linalg
from .base import AbstractProjector, ProjectionContext, switch_delay
from .predict import first_root, hermite_excursion, secant_crossing


# A step that starts this fraction of its size or less before a switch treats the switch as
# at its start (the controller's `EVENT_SKIP`: it steps over events that close).
START_SKIP = 1e-2
# The fraction of the controller's tolerance within which a switch ahead is not landed on
# (`EventLocated._negligible`).
NEGLIGIBLE = 0.25


class EventLocated(AbstractProjector):
    r"""`projector` unchanged, plus event location on a switching surface $s(t, y) = 0$.

    When a component of $s$ changes sign between the two ends of a step, the switch
    happened inside it and the scheme integrated part of the step with the wrong branch: a
    local error of order $h$ times the jump of the vector field that Richardson
    extrapolation or an embedded pair cannot see (both ends lie on the same branches). The
    `violation` is then $\min(|s_0|, |s_1|)$, which adaptive controllers count as error, so
    the step shrinks until the switch lies within tolerance of a step boundary.

    Used by the relay, diode and saturation effects of scenes; wrap your own projectors the
    same way. `surface(t, y, args)` receives the full state.

    `saltation=True` declares that the projected components (multipliers) jump across the
    switch while the vector field is otherwise continuous, as a relay's selection
    $w = \pm 1$ does: a stage that crosses the surface transversally (no sliding at its
    end) then carries the event-time sensitivity (see `switch_shift`). Leave it `False`
    when the multipliers are continuous across the switch (a diode with series
    resistance, a saturation): the vector field has a kink there, not a jump, and no
    first-order term is missing. The surface must then have a whole number of components
    per projected component (row $k m + i$ belongs to component $i$ of $m$, as a
    saturation's lower and upper surfaces do). Derivatives at such a kink take the
    element of the branch the flow follows for most of the stage: the start's for a
    stage that crosses in its second half (the controller lands steps just past
    switches), the end's for one that crosses in its first half (see `_start_branch`
    and `early_kinks`).
    """

    projector: AbstractProjector
    surface: Callable[[Any, Any, Any], Any]
    saltation: bool = eqx.field(static=True, default=False)

    def validate(self, n: int) -> None:
        self.projector.validate(n)

    def __call__(self, z, ctx: ProjectionContext):
        out = self.projector(z, ctx)
        if self.saltation or not ctx.tangent:
            return out
        return self._start_branch(z, out, ctx)

    def _start_branch(self, z, out, ctx: ProjectionContext):
        r"""The derivative's element at the solution of a stage that crossed a kink
        (`saltation=False`) in its second half: the wrapped projector's, on the branch of
        the stage's start.

        The stage collocates at its end, so its sensitivity integrates the end branch's
        Jacobian over the whole stage, while the flow followed the start branch up to the
        switch. When the controller lands a step just past the switch, that is almost
        the whole step: an error of order $h$ times the jump of the Jacobian, which does
        not vanish with the tolerance when the step at the switch does not shrink (a diode
        turning off with $h\,/(R_s C) \approx 0.2$: $d v/d R_L$ 6% off just after the
        switch, measured before event landing put steps just short of switches; the
        half-wave rectifier's derivatives are now the same without this element). The
        value is unchanged; the derivative is that of the projector at
        $z + 2(w_0 - w_1)$, which lies on the start's side of a kink between bound and
        interior (box, orthant) for a selection $w$ that moved from $w_0$ to $w_1$.
        Components whose surface changed sign in the stage's first half keep the end
        branch, the better one there. The multipliers the stage returns keep the end
        branch's element (see `AbstractNonlinearSolver.solve`): the next step starts there."""
        late = self._kink_crossings(ctx)[1]
        w0 = ctx.restrict(ctx.y_prev)
        start = self.projector(z + jax.lax.stop_gradient(2 * (w0 - out)), ctx)
        moved = jax.lax.stop_gradient(out) + (start - jax.lax.stop_gradient(start))
        return jnp.where(late, moved, out)

    def _kink_crossings(self, ctx: ProjectionContext):
        # (early, late): components whose surface changed sign in the first or second half
        # of the stage (by the secant of s); no gradient.
        s0 = jnp.atleast_1d(self.surface(ctx.t - ctx.h, ctx.y_prev, ctx.args))
        s1 = jnp.atleast_1d(self.surface(ctx.t, ctx.y_iter, ctx.args))
        crossed = s0 * s1 <= 0
        m = ctx.restrict(ctx.y_prev).shape[0]

        def per_component(mask):  # surface rows k m + i belong to component i
            if mask.size % m:
                return jnp.broadcast_to(jnp.any(mask), (m,))
            return jnp.any(mask.reshape(-1, m), axis=0)

        early = per_component(crossed & (jnp.abs(s0) < jnp.abs(s1)))
        late = per_component(crossed & (jnp.abs(s1) < jnp.abs(s0)))
        return jax.lax.stop_gradient(early), jax.lax.stop_gradient(late)

    @property
    def has_kinks(self) -> bool:
        return not self.saltation

    def early_kinks(self, ctx: ProjectionContext):
        if self.saltation:
            return super().early_kinks(ctx)
        return self._kink_crossings(ctx)[0]

    def acts_on(self, n: int) -> np.ndarray:
        return self.projector.acts_on(n)

    def weighed_rows(self, n: int) -> np.ndarray:
        return self.projector.weighed_rows(n)

    def _value(self, ctx: ProjectionContext, t, y):
        # The switching functions at (t, y), at least 1-D, in the state's dtype.
        return jnp.atleast_1d(self.surface(t, y, ctx.args)).astype(y.dtype)

    def _along(self, ctx: ProjectionContext, t, y, y_dot):
        # (s, s') at (t, y) with s' = d_t s + grad s . y_dot, the rate along the flow y_dot.
        t = jnp.asarray(t, y.dtype)
        value = lambda t, y: self._value(ctx, t, y)
        return jax.jvp(value, (t, y), (jnp.ones_like(t), jnp.asarray(y_dot, y.dtype)))

    def _end_rates(self, ctx: ProjectionContext):
        # (s0', s1'): the switching functions' rates at the step's two ends, along the
        # start's and the end's rates.
        ds0 = self._along(ctx, ctx.t - ctx.h, ctx.y_prev, ctx.start_rate)[1]
        ds1 = self._along(ctx, ctx.t, ctx.y_iter, ctx.end_rate)[1]
        return ds0, ds1

    def initial_violation(self, ctx: ProjectionContext):
        return self.projector.initial_violation(ctx)

    def impulsive(self, ctx: ProjectionContext):
        return self.projector.impulsive(ctx)

    def impact(self, ctx: ProjectionContext):
        return self.projector.impact(ctx)

    def switched(self, ctx: ProjectionContext):
        s0 = jnp.atleast_1d(self.surface(ctx.t - ctx.h, ctx.y_prev, ctx.args))
        s1 = jnp.atleast_1d(self.surface(ctx.t, ctx.y_iter, ctx.args))
        return jnp.any(s0 * s1 < 0) | self.projector.switched(ctx)

    def next_event(self, ctx: ProjectionContext):
        r"""The first zero of the switching function $s$ (or the wrapped projector's own
        prediction if earlier), from its values $s_0, s_1$ at the two ends of the attempt
        and its rates $\dot s_0, \dot s_1$ there ($\partial_t s + \nabla s \cdot y'$,
        from `ctx.start_rate` and `ctx.end_rate`; the start rate is that of the start's
        selection, the branch the flow follows up to the switch):

        - $s$ changed sign: the zero of the secant through $s_0$ and $s_1$, inside the
          attempt.
        - $s$ ends on the surface (a landing in a sliding mode: the end is no witness of
          when it got there): the zero of the start's tangent line $s_0 + \dot s_0\tau$.
        - $s$ keeps its sign: the first zero ahead of the quadratic with $q(-h) = s_0$,
          $q(0) = s_1$, $q'(0) = \dot s_1$. A secant misses the acceleration of an
          approach to a sliding surface: the steps it proposed overshot the switch, and
          each overshoot was rejected (the relay at rtol 1e-4: five rejections on the way
          in, 46 attempts in all; 34 with this prediction).
        - With `saltation`, where the next step starts on another branch (`ctx.y_next`,
          `ctx.next_rate`: a switch at the end, which `start_selection` moves to that
          step's start), the zero of the far branch's tangent line from there instead of
          the quadratic, which would bend with the jump of the rate. A switch at the
          attempt's start (within `START_SKIP` of it: the start's) is replaced by its
          surface's next zero ahead, and, with `ctx.after_end`, so is one at its end:
          the next step starts on it, and the one after it sizes that step. Two relays
          that take turns (a Filippov spiral) then switch once per step, every step
          landing on the next switch.

        Without the rates (a context that does not carry them), the secant through $s_0$
        and $s_1$. `inf` where nothing is predicted."""
        s0 = self._value(ctx, ctx.t - ctx.h, ctx.y_prev)
        s1 = self._value(ctx, ctx.t, ctx.y_iter)
        own = secant_crossing(s0, s1, ctx.h)
        ahead = jnp.full_like(own, jnp.inf)
        if ctx.start_rate is not None and ctx.end_rate is not None:
            own, ahead = self._predict(ctx, s0, s1, own)
        if self.saltation:
            # A switch this close to the start is the start's (`start_selection` moved it
            # there): predicting it would hide the events the step still holds. With two
            # relays, a step starting 1.5e-10 before one switch and landing on the other
            # surface 0.043 later reported 1.5e-10, and backward Euler's late-switch
            # charge vanished with it: a Filippov spiral jumped to its Zeno point at
            # t = 0.16 instead of 1.08, `successful`.
            # Its surface's next switch is predicted from the step's end, as for a
            # component that did not switch: the spiral's relays take turns, and the one
            # switched at a step's start is the next step's next event.
            own = jnp.where(own <= START_SKIP * ctx.h, ahead, own)
            if ctx.after_end:
                # A switch inside the attempt (crossed) or at its end (a landing, or within
                # `START_SKIP` of it: the next step's start takes it) is past: the one
                # after it sizes the next step.
                end = (1 + START_SKIP) * ctx.h
                own = jnp.where(own <= end, ahead, own)
                own = jnp.where((own <= end) | self._negligible(ctx, own), jnp.inf, own)
        own = jnp.min(own, initial=jnp.inf)
        return jnp.minimum(own, self.projector.next_event(ctx))

    def _predict(self, ctx: ProjectionContext, s0, s1, secant):
        ds0, ds1 = self._end_rates(ctx)
        h = jnp.where(ctx.h > 0, ctx.h, 1.0)
        away0, away1 = _off_surface(s0, s1)
        landed = away0 & ~away1
        reach = jnp.minimum(first_root(s0, ds0, jnp.zeros_like(s0)), h)
        # Off the surface at the end, not crossed inside the step (a start on the
        # surface, to round-off, is no crossing: the relay switched there).
        off = away1 & ((s0 * s1 > 0) | ~away0)
        ahead = h + jnp.where(
            self._switches_at_end(ctx, ds1),
            self._ahead_of_switch(ctx, s1, h),
            first_root(s1, ds1, 2 * (ds1 - (s1 - s0) / h) / h),
        )
        out = jnp.where(landed & jnp.isfinite(reach), reach, secant)
        return jnp.where(off, ahead, out), jnp.where(away1, ahead, jnp.inf)

    def _negligible(self, ctx: ProjectionContext, own):
        # Switches ahead that every state row reaches within `NEGLIGIBLE` of its
        # tolerance (atol + rtol |y|, per row as the error norm scales it: the
        # multipliers' O(1) values must not widen the states' tolerance). Stepping over
        # one costs at most about twice that (the branch's rate applied up to it),
        # which the error estimates charge. Landing on each instead resolved a Zeno
        # point's switchings down to round-off (a weakly coupled spiral: 20 000 steps
        # at every rtol; with the reference's h_min = 1e-10, a stall).
        if ctx.tolerance is None or ctx.next_rate is None:
            return jnp.zeros(own.shape, bool)
        rtol, atol = ctx.tolerance
        per_time = jnp.max(jnp.abs(ctx.next_rate) / (atol + rtol * jnp.abs(ctx.y_next)))
        return (own > ctx.h) & ((own - ctx.h) * per_time <= NEGLIGIBLE)

    def _switches_at_end(self, ctx: ProjectionContext, ds1):
        # Whether the next step starts on another branch than the step ended on (its
        # start flips a selection, see `start_selection`): the rates of s change there.
        if ctx.next_rate is None:
            return jnp.zeros(ds1.shape, bool)
        return self._along(ctx, ctx.t, ctx.y_next, ctx.next_rate)[1] != ds1

    def _ahead_of_switch(self, ctx: ProjectionContext, s1, h):
        # After a switch at the end, the tangent line of the far branch from the next
        # step's start (which a switch moved there has shifted along the jump of the
        # rate): the quadratic through the step's values would bend with the jump. The
        # switch the next step starts on (within `START_SKIP` of it) is that step's.
        if ctx.next_rate is None:
            return jnp.full_like(s1, jnp.inf)
        s_next, ds1 = self._along(ctx, ctx.t, ctx.y_next, ctx.next_rate)
        tau = first_root(s_next, ds1, jnp.zeros_like(s1))
        return jnp.where(tau <= START_SKIP * h, jnp.inf, tau)

    @property
    def has_event_time(self) -> bool:
        return self.projector.has_event_time

    def event_time(self, ctx: ProjectionContext):
        return self.projector.event_time(ctx)

    @property
    def has_switch_shift(self) -> bool:
        return self.saltation or self.projector.has_switch_shift

    def switch_shift(self, ctx: ProjectionContext):
        r"""With `saltation`, for each surface component $s$ and its projected component
        $w$ (the selection, e.g. a relay's $\pm 1$), switch time
        $\tau = -s_0/\dot s^-$ with $\dot s^- = \partial_t s + \nabla s \cdot$
        `ctx.rate` at the stage start:

        - a crossing: $s$ changes sign between the stage start and its solution while
          $w$ moves from one boundary point of its set to another (it stays put when
          pushed further along its jump at both ends): the base shift $(w^- - w^+)\,
          \delta\tau$;
        - a transient landing: the stage ends on the surface ($s_1 = 0$ up to round-off,
          $w$ inside its set) although the flow crosses it (on the far branch $w^+$, the
          point of the set farthest along $w_1 - w^-$, $\dot s^+$ has the sign of
          $\dot s^-$), so the next stage leaves on the far side and no longer carries
          $d\tau$: the end shift $(w^+ - w^-)\,\kappa$ with
          $\kappa = -\dot s^+ \delta\tau / (\dot s^+ - \dot s^-)$, which moves $s$ by
          $-\dot s^+\,d\tau$ (the exact solution is $\dot s^+ (t - \tau)$ off the
          surface).

        Both are multiplier displacements, mapped through the vector field by the model.
        Entry into a lasting sliding mode and exit from it carry no term (the state on the
        surface does not depend on the entry time; the exit is tangential)."""
        base, end, found = self.projector.switch_shift(ctx)
        if not self.saltation or ctx.rate is None:
            return base, end, found
        t0 = ctx.t - ctx.h
        dtype = ctx.y_prev.dtype
        s0, sdot = self._along(ctx, t0, ctx.y_prev, ctx.rate)
        s1 = self._value(ctx, ctx.t, ctx.y_iter)
        w0, w1 = ctx.restrict(ctx.y_prev), ctx.restrict(ctx.y_iter)
        jump = w1 - w0
        settled = (self.projector(w1 + jump, ctx) == w1) & (self.projector(w0 - jump, ctx) == w0)
        crossed = (s0 * s1 < 0) & (jump != 0) & settled
        # Transient landing: the far branch, and the rate of s on it at the start.
        # Along the jump's direction, far enough to reach the set's far side whatever the
        # jump's size: a selection that landed 3.5e-7 off its face (1e6 times that
        # reached only -0.645 of the relay's [-1, 1]) took a seventh of the far branch's
        # jump, d x(T)/d x0 0.86 instead of 0.22 (Bathe, rtol 1e-5).
        scale = jnp.max(jnp.abs(jump), initial=0.0)
        reach = 1e6 * (1.0 + jnp.max(jnp.abs(w0), initial=0.0))
        far = self.projector(w0 + reach * jump / jnp.where(scale > 0, scale, 1.0), ctx)
        y_far = ctx.y_prev if ctx.block is None else ctx.y_prev.at[np.asarray(ctx.block)].set(far)
        # A landing puts s at round-off of the surface (the projection pins it there); a
        # sqrt(eps) band would also count a step that merely ends close to the surface,
        # and would then shift it as if it had landed.
        tol = 64 * jnp.finfo(dtype).eps * (1.0 + jnp.abs(s0))
        landed = (jnp.abs(s1) <= tol) & (jnp.abs(s0) > tol) & (jump != 0) & ~settled
        if ctx.rate_at is None:
            transient = jnp.zeros_like(landed)
        else:
            _, sdot_far = self._along(ctx, t0, y_far, ctx.rate_at(y_far))
            transient = landed & (sdot_far * sdot > 0)
        delta = switch_delay(s0, sdot, crossed | transient)
        # A transient landing's base shift is the jump to the far branch (the stage's
        # pinned state ignores it; a multistage scheme reads it for its earlier points).
        target = jnp.where(crossed, w1, far)
        base = base - jnp.where(crossed | transient, (target - w0) * delta, 0.0)
        # The landed state is pinned to the surface, while the flow leaves it on the far
        # branch at the rate sdot_far from tau on: the multiplier displacement whose
        # effect on s is -sdot_far * dtau (it moves the state along the jump f+ - f-).
        gap = jnp.where(transient, sdot_far - sdot, 1.0)
        end = end + jnp.where(transient, (far - w0) * (-sdot_far / gap) * delta, 0.0)
        return base, end, found | jnp.any(crossed | transient)

    @property
    def has_start_selection(self) -> bool:
        return self.saltation

    def start_selection(self, ctx: ProjectionContext):
        r"""With `saltation`, a selection whose surface component is at the surface at the
        step's start ($|s_0|$ at round-off), or reaches it within `START_SKIP` of the step
        along the start rate (a step that starts just short of a switch, as the controller
        lands them), is replaced by the one that keeps $\dot s = 0$ there (the equivalent
        control, one Newton step on $\dot s(w) = 0$, exact for a vector field affine in
        $w$), projected onto its set: if it lies outside, the flow crosses or leaves the
        surface and the projection gives the selection of the side it goes to. Inside a
        sliding mode the previous step's multiplier already is that selection (the step
        changes nothing); after a landing step it is an average over that step, which,
        used as the start rate, pushes the next step off the surface (or makes it report a
        multiplier of about twice the equivalent control). Components off the surface, or
        whose $\dot s$ does not depend on their selection, keep their value. Returns the
        selection and the time to the surface it skips (0 on the surface)."""
        w0 = ctx.restrict(ctx.y_prev)
        zero = jnp.zeros((), ctx.y_prev.dtype)
        if not self.saltation or ctx.rate_at is None or ctx.block is None:
            return w0, zero
        t0 = ctx.t - ctx.h
        dtype = ctx.y_prev.dtype
        idx = np.asarray(ctx.block)

        def sdot(w):
            y = ctx.y_prev.at[idx].set(w)
            return self._along(ctx, t0, y, ctx.rate_at(y))[1]

        s0 = self._value(ctx, t0, ctx.y_prev)
        eps = jnp.finfo(dtype).eps
        rate, jac = sdot(w0), jax.jacfwd(sdot)(w0)
        tol = 64 * eps * (1.0 + jnp.max(jnp.abs(ctx.y_prev)))
        approaching = s0 * rate < 0
        delay = jnp.where(approaching, -s0 / jnp.where(approaching, rate, 1.0), jnp.inf)
        at = jnp.abs(s0) <= tol
        near = at | (delay <= START_SKIP * ctx.h)
        scale = jnp.max(jnp.abs(jac), initial=0.0)
        on = near & (jnp.abs(jnp.diagonal(jac)) > eps * scale)
        pair = on[:, None] & on[None, :]
        eye = jnp.eye(w0.size, dtype=dtype)
        step = _linalg.solve_or_nan(jnp.where(pair, jac, eye), jnp.where(on, rate, 0.0))
        w = jnp.where(on, self.projector(w0 - step, ctx), w0)
        # The skipped time keeps its derivative (d tau = -d s0 / sdot): the model moves the
        # start along the jump of the rate by it (in value too), the saltation term of the
        # switch moved to the start. A start on the surface to round-off carries it too when
        # the selection flips from one boundary point of its set to another (a transversal
        # crossing; the previous stage ended short of the surface, so it carried none): a
        # step that ended 3e-17 short of a relay's switch lost the switch's term entirely
        # (d x(T)/d x0 = 1 instead of 0.22). Entering or leaving a sliding mode there
        # carries none (see `switch_shift`).
        jump = w - w0
        settled = (self.projector(w + jump, ctx) == w) & (self.projector(w0 - jump, ctx) == w0)
        flips = at & on & (jump != 0) & settled & (rate != 0)
        tau = -s0 / jnp.where(flips, rate, 1.0)
        tau = jax.lax.stop_gradient(jnp.abs(tau)) + tau - jax.lax.stop_gradient(tau)
        skipped = jnp.where(on & ~at, delay, jnp.where(flips, tau, 0.0))
        # The model shifts the start by the skipped time in value: a flip at round-off
        # whose rate is tiny would give a time far beyond the step. No switch is moved
        # from further than `START_SKIP` of the step.
        skipped = jnp.where(jnp.abs(skipped) <= START_SKIP * ctx.h, skipped, 0.0)
        # The largest by indexing, so that the derivative of a value of 0 (on the surface)
        # is not halved by a tie, as `max` would.
        return w, skipped[jnp.argmax(skipped)]

    def violation(self, ctx: ProjectionContext):
        r"""A switch inside the step, in the units of $s$: where $s$ changed sign between
        the ends, the smaller of $|s_0|, |s_1|$; where both ends lie on the same side but
        the cubic Hermite interpolant through the end values and rates
        (`ctx.start_rate`, `ctx.end_rate`) crosses the surface and back, how far it
        reaches across (`hermite_excursion`). The second is a pair of switches that the
        end values alone do not show: a diode bridge at `rtol = 1e-4` stepped over a
        whole conduction pulse in one step of 7.8 ms and ended 9% off, `successful`."""
        s0 = self._value(ctx, ctx.t - ctx.h, ctx.y_prev)
        s1 = self._value(ctx, ctx.t, ctx.y_iter)
        crossed = s0 * s1 < 0
        if ctx.start_rate is not None and ctx.end_rate is not None:
            ds0, ds1 = self._end_rates(ctx)
            crossed = crossed & ~self._switched_at_start(ctx, s0, ds0)
        size = jnp.where(crossed, jnp.minimum(jnp.abs(s0), jnp.abs(s1)), 0.0)
        if ctx.start_rate is not None and ctx.end_rate is not None:
            away0, away1 = _off_surface(s0, s1)
            away = away0 & away1
            excursion = hermite_excursion(s0, s1, ctx.h * ds0, ctx.h * ds1)
            size = jnp.maximum(size, jnp.where(away, excursion, 0.0))
        own = jnp.max(size, initial=0.0).astype(ctx.y_iter.dtype)
        return jnp.maximum(own, self.projector.violation(ctx))

    def _switched_at_start(self, ctx: ProjectionContext, s0, ds0):
        # With `saltation`, the switches `start_selection` moves to the step's start (the
        # start's tangent reaches the surface within `START_SKIP` of the step): the step
        # starts on their far branch, from the state shifted to match, so crossing them
        # is no error. Counted, a step landing 1e-8 of its size short of a switch
        # crossed it by that much, at every step size: above a tolerance of 1e-8, every
        # retry was rejected until `h_min`.
        if not self.saltation:
            return jnp.zeros(s0.shape, bool)
        approaching = s0 * ds0 < 0
        delay = -s0 / jnp.where(approaching, ds0, 1.0)
        return approaching & (delay <= START_SKIP * ctx.h)


def _off_surface(s0, s1):
    # Whether each end lies off the surface by more than round-off.
    tiny = 64 * jnp.finfo(s1.dtype).eps * (1.0 + jnp.maximum(jnp.abs(s0), jnp.abs(s1)))
    return jnp.abs(s0) > tiny, jnp.abs(s1) > tiny


class ResidualSurface(eqx.Module):
    """The switching function of selection rows written as a variational inequality on an
    algebraic row, $w \\in K$ with row $0 = f_w(t, y)$ (a relay $w \\in
    \\operatorname{sign}(s)$ as $w \\in [-1, 1]$ with $f_w = s$): $f_w$ itself, whose sign
    picks the face of $K$. A module rather than a closure, so that equal models hash
    equally and compiled solves are reused."""

    vector_field: Callable
    rows: tuple[int, ...] = eqx.field(static=True)

    def __call__(self, t, y, args):
        return jnp.asarray(self.vector_field(t, y, args))[np.asarray(self.rows)]


def locate_selections(projector: AbstractProjector, vector_field, selection_rows):
    r"""`projector` with every block of a [`nivpjax.BlockProjector`][] that is an interval
    or orthant ([`nivpjax.Box`][], [`nivpjax.NonNegative`][]) on selection rows (algebraic
    rows that are not equation rows) wrapped in [`nivpjax.EventLocated`][] with
    `saltation=True` on its rows' residual $f_w$ (`ResidualSurface`): the switches of a
    relay written by hand get the event prediction, location, right-limit selections and
    sensitivities of a scene's [`nivpjax.Relay`][]. Without them, error estimates see
    nothing of a switch whose face both ends of a step agree on: backward Euler crossed
    a Filippov spiral's surfaces with zero estimated error and reached its Zeno point at
    t = 0.22 instead of 1.08, `successful`. Other projectors are returned unchanged."""
    from .block import BlockProjector
    from .box import Box, NonNegative

    if not isinstance(projector, BlockProjector):
        return projector
    selection_rows = np.asarray(selection_rows, bool)
    blocks = []
    for indices, block in projector.blocks:
        rows = np.asarray(indices, int)
        if isinstance(block, (Box, NonNegative)) and rows.size and selection_rows[rows].all():
            surface = ResidualSurface(vector_field, tuple(int(i) for i in rows))
            block = EventLocated(block, surface, saltation=True)
        blocks.append((indices, block))
    return BlockProjector(blocks)
