r"""The event-driven stepper: an explicit Runge–Kutta pair on the frozen smooth system,
cut at the first event located on its dense output."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._model import Model
from .._nonlinear import AbstractNonlinearSolver
from .._results import RESULTS
from .._solution import StepStats
from .base import AbstractStepper, StepOutput, default_solver
from .bathe import Bathe
from .event_locate import SAMPLES, first_bracket, illinois
from .frozen import algebraic_values, candidates, freeze, frozen_rate, holds, on_face, switching
from .rk_tableau import DOPRI5, ExplicitPair


# A step whose first event lies within this fraction of it is handed over to the fallback
# (time stepping): the events are denser than the error control's smooth step by this
# factor, an accumulation (a Zeno point, chattering) rather than an isolated event.
ACCUMULATION = 1e-3


def check_model(model: Model) -> None:
    """The models the event-driven stepper freezes: set-valued laws on algebraic rows
    only (relays, saturations, diodes written on multipliers). Raises `ValueError` before
    any work otherwise."""
    n = model.algebraic.shape[0]
    if model.has_impulses:
        raise ValueError(
            "`EventDriven` does not handle impacts yet (a projector with impulses); use "
            "`Bathe` or another time-stepping stepper."
        )
    on_differential = np.asarray(model.projector.acts_on(n), bool) & ~np.asarray(
        model.algebraic, bool
    )
    if on_differential.any():
        rows = np.flatnonzero(on_differential).tolist()
        raise ValueError(
            f"`EventDriven` freezes set-valued laws on algebraic rows only; the projector "
            f"acts on differential rows {rows} (friction as a proximal map, a constraint "
            "on a state). Write the law on a multiplier, or use `Bathe`."
        )


class EventDriven(AbstractStepper):
    r"""An event-driven stepper: high order between events, each event located.

    Between two events the model is smooth once the face of every set-valued law is held
    fixed (see `nivpjax._stepper.frozen`): a relay at $w = \pm 1$ or sliding with its
    equivalent control, a saturation saturated or linear. Each step

    1. decides the face at its start from the state (a state on a switching surface
       takes the side the flow goes to);
    2. integrates the frozen system with an explicit Runge–Kutta pair (`tableau`,
       default Dormand–Prince 5(4)) and its embedded estimate (error order 5);
    3. samples the switching functions of the face on the pair's continuous extension
       (order 4) at `SAMPLES` points, so that two crossings inside one step are seen, and
       locates the first sign change by the Illinois method to round-off;
    4. if there is one, ends the step there (`StepOutput.h_taken`), and decides the new
       face: the row whose switching function reached zero takes each other face of its
       set (interior, either bound), and the one whose frozen flow holds from the event
       (every switching function positive, or zero and rising) is kept. That is
       Filippov's choice between crossing and sliding, and the side a sliding mode
       leaves to (the event logic of Piiroinen and Kuznetsov); none holding is a failure.

    Events are the sign changes of the switching functions of rows at a bound (a crossing) and
    interior multipliers reaching a bound of their set (a sliding mode's exit). The event
    time carries its sensitivity: the implicit function theorem on the switching
    function moves the event state along the pre-event flow and the new face's flow back
    (the saltation term $(f^- - f^+)\,d\tau$, zero in value).

    Where events accumulate (a Zeno point, chattering: the first event of a step within
    `ACCUMULATION` of the step the error control allows, or no face holding after it),
    the step is handed over to `fallback` (default [`nivpjax.Bathe`][]; `None` ends such
    a run with a failure code instead), charged with the violation and held exit the
    loop charges time-stepping steps, and the next steps are event-driven again.

    Limits (the stepper refuses what it does not handle, before any work): laws on
    differential rows (friction as a proximal map, contacts with impacts); separable
    sets only (a box per row: relays, saturations, diodes on multipliers). Non-stiff
    frozen systems (explicit pair).

    **Arguments:**

    - `solver`: solves the consistent initial state (as for the other steppers).
    - `tableau`: the explicit pair (default Dormand–Prince 5(4)).
    - `fallback`: the time-stepping stepper for accumulating events, or `None`.
    """

    solver: AbstractNonlinearSolver = eqx.field(default_factory=default_solver)
    tableau: ExplicitPair = eqx.field(static=True, default=DOPRI5)
    fallback: AbstractStepper | None = eqx.field(default_factory=Bathe)

    @property
    def order(self) -> int:
        return self.tableau.order

    @property
    def error_order(self) -> int:
        return self.tableau.order

    @property
    def locates_events(self) -> bool:
        return True

    def validate_model(self, model: Model) -> None:
        check_model(model)

    def step(self, model, t0, h, y0, args):
        out = self._frozen_step(model, t0, h, y0, args)
        if self.fallback is None or not model.has_algebraic:
            return out
        # Events accumulating: the first one lies within ACCUMULATION of the step the
        # error control allows (a Zeno point, chattering), or no face holds after it.
        # Time stepping takes the step.
        failed = out.stats.nonlinear_result != RESULTS.successful
        handover = (out.h_taken < ACCUMULATION * h) | failed
        return jax.lax.cond(
            handover,
            lambda: self._handed_over(model, t0, h, y0, args),
            lambda: out,
        )

    def _handed_over(self, model, t0, h, y0, args):
        # The fallback's step, charged (as the loop charges time-stepping steps) with the
        # violation of a constraint it crossed and a held phase it left inside the step,
        # in state units on every row (a floor under the error norm).
        out = self.fallback.step(model, t0, h, y0, args)
        t1 = t0 + h
        violation = model.violation(t1, h, y0, out.y1, args)
        left, _ = model.held_exit(t1, h, y0, out.y1, args)
        floor = jax.lax.stop_gradient(jnp.maximum(violation, left))
        y_error = jnp.zeros_like(out.y1) if out.y_error is None else out.y_error
        y_error = jnp.where(jnp.abs(y_error) > floor, y_error, floor)
        return StepOutput(
            out.y1, y_error, out.multipliers, out.stats, h_taken=jnp.asarray(h, out.y1.dtype)
        )

    def dense_output(self, model, t, t0, y0, t1, y1, args):
        r"""The continuous extension (order 4) of the frozen step from `(t0, y0)` over
        `[t0, t1]`, recomputed from the saved step's start, with its algebraic rows solved
        on the frozen face at `t`. It vouches for the step where the recomputed end
        agrees with `y1` on the differential rows (to $10^{-3}(1 + |y_1|)$: a step of
        the pair, cut at its event or not); a step handed over to the fallback does not,
        and takes the loop's interpolant."""
        if not self.tableau.dense_order:
            return None
        sg = jax.lax.stop_gradient
        h = t1 - t0
        frozen = freeze(model, t0, h, y0, args)
        start = algebraic_values(model, frozen, t0, y0, args)
        K = self._stages(model, frozen, t0, h, start, args)
        coefficients = lambda theta: jnp.asarray(self.tableau.dense(theta), y0.dtype)  # noqa: E731
        theta = jnp.clip((t - t0) / h, 0.0, 1.0)
        value = algebraic_values(model, frozen, t, start + h * (coefficients(theta) @ K), args)
        end = start + h * (coefficients(jnp.ones_like(theta)) @ K)
        gap = jnp.where(model.algebraic, 0.0, jnp.abs(sg(end) - sg(y1)))
        usable = jnp.all(gap <= 1e-3 * (1 + jnp.abs(sg(y1))))
        return value, usable

    def _frozen_step(self, model, t0, h, y0, args):
        T = self.tableau
        face = freeze(model, t0, h, y0, args)
        y0 = algebraic_values(model, face, t0, y0, args)
        K = self._stages(model, face, t0, h, y0, args)
        y1 = algebraic_values(model, face, t0 + h, y0 + h * (jnp.asarray(T.b, y0.dtype) @ K), args)
        y_error = h * (jnp.asarray(T.b_error, y0.dtype) @ K)
        success = StepStats(
            iterations=jnp.zeros((), jnp.int32),
            residual_norm=jnp.zeros((), y0.dtype),
            nonlinear_result=RESULTS.successful,
        )
        zeros = jnp.zeros_like(y1)
        if not model.has_algebraic:
            return StepOutput(y1, y_error, zeros, success, h_taken=jnp.asarray(h, y0.dtype))

        def dense(theta):
            return y0 + h * (jnp.asarray(T.dense(theta), y0.dtype) @ K)

        def phi(theta):
            t = t0 + theta * h
            y = algebraic_values(model, face, t, dense(theta), args)
            return jnp.min(switching(model, face, t, y, args))

        sg = jax.lax.stop_gradient
        # The start too: a face that does not hold there was decided wrongly (below).
        thetas = jnp.arange(0, SAMPLES + 1, dtype=y0.dtype) / SAMPLES
        samples = sg(jax.vmap(phi)(thetas))
        found, k = first_bracket(samples[1:])

        def event(_):
            return self._at_event(model, face, t0, h, y0, args, dense, phi, k)

        def no_event(_):
            return y1, success, jnp.ones((), y0.dtype)

        y_new, stats, theta = jax.lax.cond(found, event, no_event, None)
        # A face that does not hold at the step's own start (a multiplier outside its set,
        # a state on the wrong side of its surface) was decided wrongly: no answer.
        scale = jnp.sqrt(jnp.finfo(y0.dtype).eps) * (1 + jnp.max(jnp.abs(y0)))
        wrong = samples[0] < -scale
        result = RESULTS.where(wrong, RESULTS.nonlinear_failure, stats.nonlinear_result)
        stats = StepStats(stats.iterations, stats.residual_norm, result)
        return StepOutput(
            y1=y_new,
            y_error=y_error,
            multipliers=zeros,
            stats=stats,
            h_taken=sg(theta * h).astype(y0.dtype),
        )

    def _stages(self, model, face, t0, h, y0, args):
        # The stage rates k_i of the frozen system, stacked (stages, n).
        T = self.tableau
        a = T.a
        ks = []
        for i, c in enumerate(T.c):
            increment = sum((a[i, j] * ks[j] for j in range(i) if a[i, j] != 0.0), 0.0)
            rate, _ = frozen_rate(model, face, t0 + c * h, y0 + h * increment, args)
            ks.append(rate)
        return jnp.stack(ks)

    def _at_event(self, model, face, t0, h, y0, args, dense, phi, k):
        # The step cut at the first event inside [theta_{k-1}, theta_k]: the state there
        # (with the event time's sensitivity) on the new face, and whether the event was
        # located and the new face decided.
        sg = jax.lax.stop_gradient
        dtype = y0.dtype
        lo = (k - 1).astype(dtype) / SAMPLES
        hi = k.astype(dtype) / SAMPLES
        sphi = lambda th: sg(phi(sg(th)))  # noqa: E731
        eps = jnp.finfo(dtype).eps
        tol = 8 * eps * (1 + jnp.abs(t0) / h)
        theta, _ = illinois(sphi, lo, hi, jnp.maximum(sphi(lo), 0.0), sphi(hi), tol)
        theta = sg(theta)
        theta_ad = theta + self._event_shift(model, face, t0, h, args, dense, theta)
        y_minus = dense(theta_ad)
        t_e = t0 + theta * h
        located = sg(phi(theta)) <= 0
        frozen_plus, decided = self._next_face(model, face, t_e, h, sg(y_minus), args)
        rate_plus, y_plus = frozen_rate(model, frozen_plus, t_e, y_minus, args)
        # Saltation: the state after the event moves back along the new flow by d tau.
        y_new = y_plus - rate_plus * h * (theta_ad - sg(theta_ad))
        ok = located & decided
        result = RESULTS.where(ok, RESULTS.successful, RESULTS.nonlinear_failure)
        zero = jnp.zeros((), dtype)
        return y_new, StepStats(jnp.zeros((), jnp.int32), zero, result), theta

    def _next_face(self, model, frozen, t_e, h, y_e, args):
        # The face after the event at (t_e, y_e): the switching row that reached zero
        # takes each other face of its set in turn (interior, lower bound, upper bound),
        # and the one whose frozen flow holds from there is the new face (Filippov's
        # choice between crossing and sliding, and a sliding mode's exit side; the
        # Piiroinen-Kuznetsov event logic). Returns it and whether one held.
        face = frozen.face
        g = switching(model, frozen, t_e, algebraic_values(model, frozen, t_e, y_e, args), args)
        row = jnp.argmin(g)
        faces = candidates(face, row)
        tol = jnp.sqrt(jnp.finfo(y_e.dtype).eps) * (1 + jnp.max(jnp.abs(y_e)))

        def judge(f):
            fz = on_face(model, f, t_e, y_e, args)
            return holds(model, fz, t_e, y_e, args, tol), fz

        valid, frozens = jax.vmap(judge)(faces)
        same = jnp.stack(
            [
                face.interior[row],
                ~face.interior[row] & (face.side[row] < 0),
                ~face.interior[row] & (face.side[row] > 0),
            ]
        )
        valid = valid & ~same
        pick = jnp.argmax(valid)
        chosen = jax.tree.map(lambda x: x[pick], frozens)
        return chosen, jnp.any(valid)

    def _event_shift(self, model, face, t0, h, args, dense, theta):
        # d theta from the implicit function theorem on the switching function that
        # vanishes at theta: -(dg)/(dg/dtheta), zero in value.
        sg = jax.lax.stop_gradient

        def g_all(th):
            t = t0 + th * h
            y = algebraic_values(model, face, t, dense(th), args)
            return switching(model, face, t, y, args)

        row = jnp.argmin(sg(g_all(theta)))
        g, g_dot = jax.jvp(lambda th: g_all(th)[row], (theta,), (jnp.ones_like(theta),))
        g_dot = sg(g_dot)
        safe = jnp.where(g_dot != 0, g_dot, 1.0)
        return jnp.where(g_dot != 0, -(g - sg(g)) / safe, 0.0)
