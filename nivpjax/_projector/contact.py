"""Velocity-level unilateral contact with Newton restitution (Moreau's sweeping process)."""

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._norms import violation_scale
from .base import AbstractProjector, Bound, ProjectionContext, resolve
from .lcp import lcp_solve
from .predict import first_root, secant_crossing


_LANDED = 1e-2


class UnilateralContact(AbstractProjector):
    r"""Impacts and resting contact for any number of contacts at once, at velocity level.

    The user describes the contacts through three maps of the state $y$:

    - `gap(t, y, args) -> (m,)`: the signed distances $g(y)$ (contact closed when $g \le 0$);
    - `velocity_map(t, y, args) -> (m, n)`: the matrix $W^T(y)$ giving the normal contact
      velocities $u = W^T(y)\,y$ (typically it picks velocity components);
    - `impulse_map(t, y, args) -> (n, m)` (optional): the state change per unit impulse,
      $B(y) = M^{-1} W$ in mechanics. Defaults to $W$ (unit masses).

    The maps always receive the full state; inside a [`nivpjax.BlockProjector`][] the
    projected vector, and so the columns of `velocity_map` and rows of `impulse_map`, are
    those of the block (e.g. the velocity components only).

    and `restitution` $e$ (scalar or per contact, array or callable). With `weighed`
    (static, default `False`; [`nivpjax.Contact`][] sets it for curved gaps), the reaction
    of the contacts that rest under a pressing flow is weighed like the vector field by
    the theta family's stages (see `weighed_rows`).

    A contact is active in a stage when it is closed at the stage's start,
    $g(y_{\text{prev}}) \le \max(16\,\varepsilon\,(1 + \|y_{\text{prev}}\|_\infty),\,
    h\,\sqrt{\varepsilon}\,(1 + \|u^-\|_\infty))$ (zero up to round-off, or closed within
    the step at a round-off velocity), and not separating faster than round-off, or its predicted
    gap
    $g(y_{\text{prev}}) + \text{lookahead}\cdot h\,u(y_{\text{prev}})$ is $\le 0$ (the default
    lookahead $1/2$ is Moreau's midpoint rule; the active set is frozen within a stage so the
    nonlinear iteration cannot cycle between sets). On the active contacts the projection solves

    $$ 0 \le p \perp W^T (z + B p) + e\,\min(u^-, 0) \ge 0, \qquad P(z) = z + B p, $$

    Newton's impact law with the pre-impact velocity $u^- = W^T y_{\text{prev}}$: the
    projection of $z$ onto $\{v : W^T v + e u^- \ge 0 \text{ on active contacts}\}$ in the
    metric of $B$. It is a projection (idempotent, non-expansive in that metric). At the
    solution of an implicit step $p$ is the contact impulse over the step.

    Jacobian: from the LCP's active set (see [`nivpjax.lcp_solve`][]); a contact exactly at
    $W^T z + e u^- = 0$ with zero impulse counts as inactive (identity, the point is
    feasible).

    Events inside a step: a contact inactive at the start of a step that ends penetrated
    reports its penetration through `violation`, which adaptive controllers treat as local
    error; the step is then shortened until the impact is located to the tolerance. A stage
    with an active approaching contact is `impulsive` (Bathe's scheme restarts its second
    stage as backward Euler after it).
    """

    gap: Callable[[Any, Any, Any], Any]
    velocity_map: Callable[[Any, Any, Any], Any]
    impulse_map: Callable[[Any, Any, Any], Any] | None = None
    restitution: Bound = 0.0
    lookahead: float = 0.5
    weighed: bool = eqx.field(static=True, default=False)

    def _start(self, ctx: ProjectionContext, dtype):
        # Everything decided at the start of the stage: contact velocities, impulse map,
        # and the active set from the predicted gap.
        y0 = ctx.y_prev
        Wt, B = self._maps(ctx.t, y0, ctx.args, dtype)
        gap0 = jnp.atleast_1d(jnp.asarray(self.gap(ctx.t, y0, ctx.args), dtype))
        u_minus = Wt @ ctx.restrict(y0)
        # A contact is active when the gap predicted over the lookahead closes, and a closed
        # contact stays active unless it separates faster than round-off (a resting contact
        # carries velocities of order eps from the previous LCP). The prediction is linear,
        # plus the normal acceleration at the start where it points away from the contact
        # (a > 0): a body approaching slowly against such an acceleration turns around
        # before it touches (a graze, e.g. an oscillator whose orbit is tangent to the
        # floor), and applying Newton's law there would be an impact the flow never has.
        # Where a <= 0 the linear prediction is the earlier (safe) one and is kept.
        lead = self.lookahead * ctx.h
        if ctx.start_rate is None:
            a = jnp.zeros_like(u_minus)
        else:
            a = self._normal_acceleration(ctx, y0, ctx.start_rate, dtype)
        predicted = gap0 + lead * u_minus + 0.5 * jnp.maximum(a, 0.0) * lead**2 <= 0
        # For the same reason a contact closed only up to round-off (gap0 > 0) is not
        # active when the quadratic model never reaches it ($u^2 < 2 a g$): in float32 the
        # round-off band (16 eps) holds a grazing orbit's closest approach.
        graze = (a > 0) & (u_minus**2 < 2 * a * gap0)
        active = (predicted | self._resting(gap0, u_minus, y0, ctx.h)) & ~graze
        return Wt, B, gap0, u_minus, active

    def _maps(self, t, y, args, dtype):
        # The normals W^T and the impulse map B at the state y.
        Wt = jnp.asarray(self.velocity_map(t, y, args), dtype)
        if Wt.ndim == 1:
            Wt = Wt[None, :]
        if self.impulse_map is None:
            return Wt, Wt.T
        return Wt, jnp.asarray(self.impulse_map(t, y, args), dtype).reshape(Wt.T.shape)

    @staticmethod
    def _roundoff_velocity(u_minus):
        # Contact velocities below this are round-off (a resting contact carries velocities
        # of order eps from the previous LCP).
        eps = jnp.finfo(u_minus.dtype).eps
        return jnp.sqrt(eps) * (1.0 + jnp.max(jnp.abs(u_minus), initial=0.0))

    @staticmethod
    def _roundoff_gap(y, dtype):
        # The round-off of a gap computed from positions of the state's size.
        return 16 * jnp.finfo(dtype).eps * (1.0 + jnp.max(jnp.abs(y), initial=0.0))

    @classmethod
    def _closed(cls, gap0, u_minus, y0, h):
        # Closed up to round-off: the round-off of the gap, or the distance a round-off
        # velocity covers in the step. A resting body whose gap drifted above zero by the
        # trapezoidal rule's rounding (~1e-17) or by an iterative solver's tolerance (the VI
        # method's 1e-10) stays in contact instead of falling for a step and micro-bouncing.
        band = cls._roundoff_gap(y0, gap0.dtype)
        return gap0 <= jnp.maximum(band, h * cls._roundoff_velocity(u_minus))

    @classmethod
    def _resting(cls, gap0, u_minus, y0, h):
        return cls._closed(gap0, u_minus, y0, h) & (u_minus <= cls._roundoff_velocity(u_minus))

    def _end(self, ctx: ProjectionContext, dtype):
        # Gaps and normal velocities at the end of the step, with the normals there (on a
        # curved gap the start's normals read a body sliding along it as approaching).
        gap1 = jnp.atleast_1d(jnp.asarray(self.gap(ctx.t, ctx.y_iter, ctx.args), dtype))
        Wt1, _ = self._maps(ctx.t, ctx.y_iter, ctx.args, dtype)
        return gap1, Wt1 @ ctx.restrict(ctx.y_iter)

    def _normal_acceleration(self, ctx: ProjectionContext, y, rate, dtype):
        # The rate of the normal velocities u = W^T(y) v along the state's rate y':
        # W^T v' plus the curvature term (dW^T/dt) v (zero for gaps linear in the
        # positions; v^2 / R on a circular wall of radius R, which the free flow leaves).
        def normal_velocity(y):
            return self._maps(ctx.t, y, ctx.args, dtype)[0] @ ctx.restrict(y)

        rate = jnp.asarray(rate, dtype)
        return jax.jvp(normal_velocity, (jnp.asarray(y, dtype),), (rate,))[1]

    def _end_acceleration(self, ctx: ProjectionContext, dtype):
        # Normal accelerations of the vector field at the end of the step (`ctx.rate`).
        rate = jnp.zeros_like(ctx.y_iter) if ctx.rate is None else ctx.rate
        return self._normal_acceleration(ctx, ctx.y_iter, rate, dtype)

    def pressed(self, ctx: ProjectionContext, dtype):
        """The contacts resting at the stage start that the free flow presses into: closed,
        neither separating nor approaching faster than round-off (an impact is not a
        persistent contact), and a negative normal acceleration of the vector field there,
        curvature included (`ctx.start_rate`; none without it). They carry a reaction
        through the stage, and [`nivpjax.HeldGaps`][] holds them on their gap."""
        y0 = ctx.y_prev
        if ctx.start_rate is None:
            return jnp.zeros(jnp.atleast_1d(self.gap(ctx.t, y0, ctx.args)).shape, bool)
        Wt, _ = self._maps(ctx.t, y0, ctx.args, dtype)
        gap0 = jnp.atleast_1d(jnp.asarray(self.gap(ctx.t, y0, ctx.args), dtype))
        u0 = Wt @ ctx.restrict(y0)
        a0 = self._normal_acceleration(ctx, y0, ctx.start_rate, dtype)
        still = jnp.abs(u0) <= self._roundoff_velocity(u0)
        return self._closed(gap0, u0, y0, ctx.h) & still & (a0 < 0)

    def _impacts(self, ctx: ProjectionContext, dtype):
        # Active contacts approaching faster than round-off at the start of the stage.
        _, _, gap0, u_minus, active = self._start(ctx, dtype)
        return gap0, u_minus, active & (u_minus < -self._roundoff_velocity(u_minus))

    def weighed_rows(self, n: int) -> np.ndarray:
        """Every row with `weighed`: a persistent contact's reaction is then a bounded
        force that turns with the normal and varies with the load along a closed phase (a
        bead against a curved wall), which a second-order stage weighs at both ends (only
        the contacts `pressed` at the point: `ProjectionContext.law`). None otherwise: on
        a flat contact the holding force stays at the stage's end."""
        return np.full(n, self.weighed, bool)

    def violation(self, ctx: ProjectionContext):
        r"""Penetration at the end of the step of contacts that were open at its start (not
        enforced, or only activated by the lookahead inside the step), and of closed
        contacts whose penetration grew in the step beyond round-off (a contact that an
        impact at the start left separating, not enforced in the stage, and that the body
        fell back through within the step). The whole penetration counts, not its growth:
        a velocity-level contact never pushes a body back out, so accepted growths would
        add up, step after step, to a body sinking through the floor.

        Such a contact is hit late, at the next step's start, by about
        $\delta t = d / |u_1|$ ($d$ the depth, $u_1 < 0$ the normal velocity at the end),
        while the normal acceleration $a$ kept acting: the velocity after the impact is
        then off by $(1 + e)\,|a|\,\delta t$ (the velocity row of the saltation term
        $(f^+ - D R\, f^-)\,\delta t$, $R$ Newton's law). That counts too: at small
        approach speeds the depth is tiny however late the impact (a ball near its Zeno
        point, bouncing at 5e-5 m/s, otherwise takes steps ten times its flights, each
        falling through the floor with an error of round-off)."""
        dtype = ctx.y_iter.dtype
        _, _, gap0, u_minus, _ = self._start(ctx, dtype)
        gap1, u1 = self._end(ctx, dtype)
        a1 = self._end_acceleration(ctx, dtype)
        is_open = ~self._closed(gap0, u_minus, ctx.y_prev, ctx.h)
        depth0, depth1 = jnp.maximum(-gap0, 0.0), jnp.maximum(-gap1, 0.0)
        tiny = self._roundoff_gap(ctx.y_prev, dtype)
        grew = depth1 > depth0 + tiny
        depth = jnp.where(is_open | grew, depth1, 0.0)
        e = jnp.broadcast_to(resolve(self.restitution, ctx, dtype), u1.shape)
        # Depths within round-off of the gap locate nothing (float32: 2e-6 m at 1 m).
        approaching = (u1 < -self._roundoff_velocity(u1)) & (depth > tiny)
        late = depth / jnp.where(approaching, -u1, 1.0)
        velocity = jnp.where(approaching, (1 + e) * jnp.abs(a1) * late, 0.0)
        judged = depth * self._depth_to_state_scale(ctx, dtype)
        return jnp.max(jnp.maximum(judged, velocity), initial=0.0)

    def _depth_to_state_scale(self, ctx: ProjectionContext, dtype):
        r"""Per contact, the factor that charges a penetration like an error in its gap:
        $s / b$, with $s$ the scale the controller charges a violation against
        (`violation_scale`, the start state's: $\text{atol} + \text{rtol}\,\|y_0\|_\infty$)
        and $b = \big(\sum_i (\partial_i g\, s_i)^2\big)^{1/2}$, $s_i = \text{atol} +
        \text{rtol} \max(|y_{0,i}|, |y_{1,i}|)$, the error norm's tolerance carried to
        the gap: the change of the gap that errors at tolerance in the components make.
        A gap with a unit gradient in the positions $q$ (a wall, a sphere) has
        $b \le \text{atol} + \text{rtol}\,\|q\|_2$ (Minkowski): $\text{atol} +
        \text{rtol}\,R$ on a ball in a bowl of radius $R$, where the state's scale
        would include the speed. A gap in other units than the positions is judged in
        its own. 1 without a tolerance (`ctx.tolerance`) or where the gap reads no row."""
        if ctx.tolerance is None:
            return jnp.ones((), dtype)
        rtol, atol = ctx.tolerance
        y0, y1 = ctx.y_prev, ctx.y_iter

        def gap(y):
            return jnp.atleast_1d(jnp.asarray(self.gap(ctx.t, y, ctx.args), dtype))

        rows = atol + rtol * jnp.maximum(jnp.abs(y0), jnp.abs(y1))
        rows = jnp.broadcast_to(rows, y1.shape).astype(dtype)
        band = jnp.sqrt(jnp.sum((jax.jacrev(gap)(y1) * rows) ** 2, axis=-1))
        scale = ctx.violation_scale
        scale = violation_scale(rtol, atol, y0) if scale is None else scale
        scale = jnp.asarray(scale).astype(dtype)
        factor = jnp.where(band > 0, scale / jnp.where(band > 0, band, 1.0), 1.0)
        return jax.lax.stop_gradient(factor)

    def next_event(self, ctx: ProjectionContext):
        r"""The first closing of a contact after the start of the attempt, from the gap's
        quadratic model $g(\tau) = g + u \tau + \tfrac12 a \tau^2$, $u = W^T v$ the normal
        velocity and $a = W^T \dot v$ the normal acceleration of the vector field at the
        attempt's end (`ctx.rate`; exact for a body under constant acceleration).

        The model runs from the start of the attempt; if it predicts no closing inside
        the attempt, it runs again from the end, after Newton's law has been applied to
        contacts that close there ($u^+ = -e u^-$): a step that lands just before an
        impact then predicts the flight after it.

        A resting contact predicts its lift-off: the zero of the normal acceleration of
        the free flow (the reaction it needs, negated) along its secant from the attempt's
        start (`ctx.start_rate`) to its end. The contact's reaction goes to zero there with
        a kink, which no error estimate sees; a step across it applies the free flow to
        the whole step in derivatives (a lift-off time off by the step's part before it:
        d v(T)/d g off by 2.2e-3 relative on a plastic contact at rtol 1e-4)."""
        dtype = ctx.y_iter.dtype
        _, _, gap0, u0, _ = self._start(ctx, dtype)
        gap1, u1 = self._end(ctx, dtype)
        a = self._end_acceleration(ctx, dtype)
        resting0 = self._resting(gap0, u0, ctx.y_prev, ctx.h)
        if ctx.start_rate is None:
            lift_off = jnp.inf
        else:
            a0 = self._normal_acceleration(ctx, ctx.y_prev, ctx.start_rate, dtype)
            lift = jnp.where(resting0, secant_crossing(a0, a, ctx.h), jnp.inf)
            lift_off = jnp.min(lift, initial=jnp.inf)
        from_start = jnp.min(jnp.where(resting0, jnp.inf, first_root(gap0, u0, a)), initial=jnp.inf)
        e = jnp.broadcast_to(resolve(self.restitution, ctx, dtype), u1.shape)
        # A step that ended within 1% of its size before a contact closes has landed on
        # it (the controllers step over so near an event, and the next step applies the
        # impact at its start). One that ended further away has not: predict that landing.
        # (Predicting the flight after it instead, whenever the next step's lookahead
        # would apply the impact, charged that impact's timing at every retry: a cascade
        # of 5 to 20 rejections, measured on balls whose step fell short of a contact.)
        landed = (gap1 <= 0) | (first_root(gap1, u1, a) <= _LANDED * ctx.h)
        closing = (gap1 + self.lookahead * ctx.h * u1 <= 0) & (u1 < 0) & landed
        gap1 = jnp.where(closing, jnp.maximum(gap1, 0.0), gap1)
        u1 = jnp.where(closing, -e * u1, u1)
        resting1 = self._resting(gap1, u1, ctx.y_iter, ctx.h)
        from_end = jnp.min(jnp.where(resting1, jnp.inf, first_root(gap1, u1, a)), initial=jnp.inf)
        return jnp.minimum(jnp.where(from_start <= ctx.h, from_start, ctx.h + from_end), lift_off)

    def initial_violation(self, ctx: ProjectionContext):
        """Initial penetration beyond round-off ($\\sqrt\\varepsilon$ relative to the state):
        a velocity-level contact cannot push a body out, so the run would stay inside."""
        y0 = ctx.y_prev
        dtype = y0.dtype
        gap0 = jnp.atleast_1d(jnp.asarray(self.gap(ctx.t, y0, ctx.args), dtype))
        tol = jnp.sqrt(jnp.finfo(dtype).eps) * (1.0 + jnp.max(jnp.abs(y0), initial=0.0))
        depth = jnp.max(jnp.maximum(-gap0, 0.0), initial=0.0)
        return jnp.where(depth > tol, depth, 0.0)

    @property
    def has_event_time(self) -> bool:
        return True

    def event_time(self, ctx: ProjectionContext):
        r"""An impact in this stage (an active contact approaching faster than round-off):
        the stage applies it from the pre-impact velocity at its start, while the flow
        meets the contact $\tau = -g(y_{\text{prev}})/u^-$ later ($\tau < 0$ when the
        located step ended slightly penetrated). With several impacts, the earliest."""
        gap0, u_minus, impact = self._impacts(ctx, ctx.y_prev.dtype)
        tau = jnp.where(impact, -gap0 / jnp.where(impact, u_minus, -1.0), jnp.inf)
        # A gap closed to round-off locates nothing: its tau is zero in value (its
        # derivative, how the landing moves with the data, is kept). A deeper penetration
        # gives tau < 0: how late the impact comes.
        closed = self._closed(jnp.abs(gap0), u_minus, ctx.y_prev, ctx.h)
        tau = jnp.where(closed & impact, tau - jax.lax.stop_gradient(tau), tau)
        found = jnp.any(impact)
        return jnp.where(found, jnp.min(tau), 0.0), found

    def switched(self, ctx: ProjectionContext):
        """A contact started or stopped resting (carrying a reaction) between the two
        ends: the acceleration jumps there. A contact that an impact leaves separating
        opens without a jump of the rate."""
        dtype = ctx.y_iter.dtype
        _, _, gap0, u0, _ = self._start(ctx, dtype)
        gap1, u1 = self._end(ctx, dtype)
        resting0 = self._resting(gap0, u0, ctx.y_prev, ctx.h)
        resting1 = self._resting(gap1, u1, ctx.y_iter, ctx.h)
        return jnp.any(resting0 != resting1)

    def impulsive(self, ctx: ProjectionContext):
        """An active contact approaching at the start of the stage is an impact (velocities
        below a round-off threshold, as a resting contact carries, are not)."""
        return jnp.any(self._impacts(ctx, ctx.y_iter.dtype)[2])

    def impact(self, ctx: ProjectionContext):
        r"""Newton's impact law at the start state on the impacting contacts (active and
        approaching faster than round-off): $0 \le p \perp W^T(v + Bp) + e u^- \ge 0$ from
        $v$ = the start velocities; other contacts are left alone."""
        z = ctx.restrict(ctx.y_prev)
        _, _, impacts = self._impacts(ctx, z.dtype)
        return self._project(z, ctx, impacts)

    def __call__(self, z, ctx: ProjectionContext):
        z = jnp.asarray(z)
        return self._project(z, ctx, None)

    def _project(self, z, ctx: ProjectionContext, active):
        _, _, _, u_minus, start_active = self._start(ctx, z.dtype)
        if ctx.law:
            start_active = self.pressed(ctx, z.dtype)
        Wt, B = self._maps(ctx.t, ctx.y_iter, ctx.args, z.dtype)
        active = start_active if active is None else active
        e = jnp.broadcast_to(resolve(self.restitution, ctx, z.dtype), u_minus.shape)
        m = u_minus.shape[0]
        D = Wt @ B
        D = jnp.where(active[:, None] & active[None, :], D, jnp.eye(m, dtype=z.dtype))
        # Restitution acts on approach velocities only: a separating contact gets u+ >= 0.
        q = jnp.where(active, Wt @ z + e * jnp.minimum(u_minus, 0.0), 0.0)
        p = lcp_solve(D, q)
        return z + B @ p
