"""The compiled time loop: the only importer of `equinox.internal`."""

import dataclasses

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp

from ._controller import AbstractController, StepInfo
from ._held import (
    held_start,
    on_second_order_surface,
    phase_begins,
    second_order_ends,
    second_order_rows,
    selection_phases,
    selections_inside,
)
from ._hermite import cubic_hermite
from ._model import Model
from ._norms import violation_scale
from ._results import RESULTS
from ._solution import AttemptLog, Solution
from ._stepper import AbstractStepper
from ._stored_loop import STORE_BUDGET_BYTES, stored_bytes, stored_while_loop


class _LoopState(eqx.Module):
    # Evolving state.
    t: jax.Array
    h: jax.Array
    h_last: jax.Array
    h_min: jax.Array  # constant: the step floor
    y: jax.Array
    controller_state: object
    # Counters.
    n_accepted: jax.Array
    n_rejected: jax.Array
    n_attempts: jax.Array
    n_iterations: jax.Array
    result: RESULTS
    # Buffers (write-only inside the loop), one row per accepted step; None when the
    # steps are not saved (`SaveAt(steps=False)`), and then never allocated.
    ts: jax.Array | None
    ys: jax.Array | None
    hs: jax.Array | None
    multipliers: jax.Array | None
    iterations: jax.Array | None
    residual_norms: jax.Array | None
    nonlinear_success: jax.Array | None
    # Buffers, one row per attempt (or None).
    attempts: AttemptLog | None
    # The states at the output times, filled in the loop when the steps are not saved
    # (NaN until the step containing a time is accepted), or None.
    y_eval: jax.Array | None = None


def _buffers(state: _LoopState):
    # Only the differentiable float arrays. Per-step counts and flags stay ordinary loop
    # state: as checkpointed-loop buffers they break its perturbation analysis under
    # reverse mode ("`where` must not depend on the leaves").
    # Without saved steps there are none: `run` passes no `buffers` then (equinox calls
    # this on trees whose `None`s are leaves, so it cannot filter them here).
    return [state.ts, state.ys, state.hs, state.multipliers, state.residual_norms]


def default_h_min(t0, t1, dtype):
    eps = jnp.finfo(dtype).eps
    return 64 * eps * jnp.maximum(jnp.maximum(jnp.abs(t0), jnp.abs(t1)), jnp.abs(t1 - t0))


def _init_attempts(max_steps, dtype):
    return AttemptLog(
        t=jnp.full((max_steps,), jnp.inf, dtype),
        h=jnp.zeros((max_steps,), dtype),
        accepted=jnp.zeros((max_steps,), dtype),
        error_norm=jnp.zeros((max_steps,), dtype),
        iterations=jnp.zeros((max_steps,), dtype),
        nonlinear_success=jnp.zeros((max_steps,), dtype),
    )


def _log_attempt(log: AttemptLog, i, t, h, accepted, err, stats):
    def put(buf, x):
        return eqxi.buffer_at_set(buf, i, jnp.asarray(x).astype(buf.dtype))

    return AttemptLog(
        t=put(log.t, t),
        h=put(log.h, h),
        accepted=put(log.accepted, accepted),
        error_norm=put(log.error_norm, err),
        iterations=put(log.iterations, stats.iterations),
        nonlinear_success=put(log.nonlinear_success, stats.nonlinear_result == RESULTS.successful),
    )


def _finish_attempts(log: AttemptLog | None) -> AttemptLog | None:
    if log is None:
        return None
    return AttemptLog(
        t=log.t,
        h=log.h,
        accepted=log.accepted > 0,
        error_norm=log.error_norm,
        iterations=log.iterations.astype(jnp.int32),
        nonlinear_success=log.nonlinear_success > 0,
    )


def held_to_control(stepper: AbstractStepper, controller: AbstractController):
    """`stepper` with its stages' nonlinear solves held `STAGE_FRACTION` times tighter
    than `controller`'s tolerances (unchanged where the solver's own are tighter, or the
    controller holds steps to none)."""
    tolerances = controller.tolerances()
    if tolerances is None:
        return stepper
    return stepper.with_solver(stepper.solver.within(*tolerances))


def init_state(
    model: Model,
    stepper: AbstractStepper,
    controller: AbstractController,
    t0,
    t1,
    y0,
    args,
    h0,
    error_mask,
    max_steps: int,
    save_attempts: bool,
    save_steps: bool = True,
    t_eval=None,
) -> _LoopState:
    """The loop state before the first attempt: the controller's first step and state,
    consistent algebraic components, empty buffers (`max_steps + 1` rows; none without
    `save_steps`, and then NaN states at `t_eval` to be filled in the loop)."""
    dtype = y0.dtype
    stepper = held_to_control(stepper, controller)
    error_order = _error_order(stepper, controller)
    h_min = controller.bounds[0]
    h_min = default_h_min(t0, t1, dtype) if h_min is None else jnp.asarray(h_min, dtype)

    def first_step(y0):
        # The controller's first step reads the rate y' at t0 (zero on algebraic rows).
        rate = model.to_state(model.f(t0, y0, args))
        h, controller_state = controller.init(t0, t1, y0, h0, rate, error_order, error_mask)
        return jnp.maximum(h, h_min), controller_state

    h, controller_state = first_step(y0)
    result0 = RESULTS.where(
        model.initial_violation(t0, h, y0, args) > 0,
        RESULTS.initial_state_infeasible,
        RESULTS.successful,
    )
    if model.has_algebraic:
        # The projection's fixed point does not depend on the stage length (it only scales
        # the iteration), so the provisional step serves; the first step is then chosen
        # from the consistent state's rate (a relay's multiplier is 0 before it is solved,
        # which would make the rate, and so the first step, wrong).
        init = model.consistent_initial_state(stepper.solver, t0, h, y0, args)
        ok = init.result == RESULTS.successful
        y0 = jnp.where(ok, init.value, y0)
        result0 = RESULTS.where(ok, result0, RESULTS.nonlinear_failure)
        h, controller_state = first_step(y0)

    return _LoopState(
        t=t0,
        h=h,
        h_last=jnp.zeros((), dtype),
        h_min=h_min,
        y=y0,
        controller_state=controller_state,
        n_accepted=jnp.array(0, jnp.int32),
        n_rejected=jnp.array(0, jnp.int32),
        n_attempts=jnp.array(0, jnp.int32),
        n_iterations=jnp.array(0, jnp.int32),
        result=result0,
        **(_step_buffers(max_steps + 1, t0, h, y0) if save_steps else _NO_STEPS),
        attempts=_init_attempts(max_steps, dtype) if save_attempts else None,
        y_eval=None if save_steps or t_eval is None else _empty_eval(t_eval, y0),
    )


_STEP_FIELDS = (
    "ts",
    "ys",
    "hs",
    "multipliers",
    "iterations",
    "residual_norms",
    "nonlinear_success",
)
_NO_STEPS = dict.fromkeys(_STEP_FIELDS)


def _step_buffers(rows, t0, h, y0):
    dtype, n = y0.dtype, y0.shape[0]
    return dict(
        ts=jnp.full((rows,), jnp.inf, dtype).at[0].set(t0),
        ys=jnp.zeros((rows, n), dtype).at[0].set(y0),
        hs=jnp.zeros((rows,), dtype).at[0].set(h),
        # Each buffer must be a distinct array object (equinox locates buffers by identity;
        # two identical `jnp.zeros` may be one cached constant).
        multipliers=jnp.zeros((rows, n), dtype).at[0].set(0.0),
        iterations=jnp.zeros((rows,), jnp.int32),
        residual_norms=jnp.zeros((rows,), dtype).at[0].set(-0.0),
        nonlinear_success=jnp.ones((rows,), bool),
    )


def _empty_eval(t_eval, y0):
    return jnp.full((t_eval.shape[0], y0.shape[0]), jnp.nan, y0.dtype)


def _error_order(stepper, controller):
    return stepper.error_order if controller.needs_error_estimate else 1


def attempt(
    s: _LoopState,
    model: Model,
    stepper: AbstractStepper,
    controller: AbstractController,
    t1,
    args,
    error_mask,
    progress=None,
    t_eval=None,
) -> _LoopState:
    """One attempted step of size `s.h` (stretched onto `t1` when close): the step, the
    controller's decision, the counters and (on acceptance) the buffers, or the states at
    the `t_eval` inside the step when the steps are not saved. Also usable outside the loop
    for manual stepping."""
    new, rows, accept = _advance(
        s, model, stepper, controller, t1, args, error_mask, progress, t_eval
    )
    return _write_rows(new, rows, s.n_accepted + 1, accept)


def _write_rows(s: _LoopState, rows: dict, idx, accept) -> _LoopState:
    # The accepted step's row of each saved-step buffer (none without saved steps).
    def put(buf, x):
        return None if buf is None else eqxi.buffer_at_set(buf, idx, x, pred=accept)

    return dataclasses.replace(
        s, **{name: put(getattr(s, name), rows[name]) for name in _STEP_FIELDS}
    )


def _advance(s: _LoopState, model, stepper, controller, t1, args, error_mask, progress, t_eval):
    # `attempt` without the buffer writes: the new state (buffers as they were), the row
    # of each saved-step buffer, and whether the step was accepted.
    stepper = held_to_control(stepper, controller)
    h_min = s.h_min
    h_max = controller.bounds[1]
    remaining = t1 - s.t
    # Land on t1 rather than leave a remainder below h_min (float accumulation of
    # fixed steps would otherwise leave a step of a few ulps).
    last = s.h >= remaining - h_min
    h_try = jnp.where(last, remaining, s.h)
    # A finished member of a vmapped batch still runs this body (its result is
    # discarded); keep its step finite so nothing divides by zero, even in reverse mode.
    h_try = jnp.where(h_try > 0, h_try, jnp.maximum(s.h, h_min))
    h_try = jax.lax.stop_gradient(h_try)
    out = stepper.step(model, s.t, h_try, s.y, args)
    y_error = jnp.zeros_like(out.y1) if out.y_error is None else out.y_error
    violation, next_event, after_end = _events(
        model, stepper, s, h_try, out, args, controller.tolerances(), error_mask
    )
    info = StepInfo(
        t0=s.t,
        h=h_try,
        t1=t1,
        y0=s.y,
        y1=out.y1,
        y_error=y_error,
        error_order=_error_order(stepper, controller),
        stats=out.stats,
        error_mask=error_mask,
        violation=violation,
        next_event=next_event,
        event_after_end=after_end,
    )
    accept, h_next, controller_state = controller.adapt(info, s.controller_state)
    accept = accept & jnp.all(jnp.isfinite(out.y1))
    # Judge the floor by the proposed step: the last step may be stretched onto t1.
    at_floor = jnp.minimum(h_try, s.h) <= h_min * (1 + 1e-6)
    floor_failure = ~accept & at_floor
    nonlinear_ok = out.stats.nonlinear_result == RESULTS.successful
    failure_code = RESULTS.where(nonlinear_ok, RESULTS.h_min_reached, RESULTS.nonlinear_failure)
    result = RESULTS.where(floor_failure, failure_code, s.result)
    h_next = jnp.maximum(h_next, h_min)
    if h_max is not None:
        h_next = jnp.minimum(h_next, h_max)
    h_next = jax.lax.stop_gradient(h_next)

    h_step = h_try
    if out.h_taken is not None:
        # A stepper that ended the step at an event it located: the state is there.
        cut = out.h_taken < h_try
        last = last & ~cut
        h_step = jnp.where(cut, jax.lax.stop_gradient(out.h_taken), h_try)
        # The controller restarts after the event: no growth beyond the attempted step.
        h_next = jnp.where(cut & accept, jnp.minimum(h_next, h_try), h_next)
    t_new = jnp.where(accept, jnp.where(last, t1, s.t + h_step), s.t)
    y_new = jnp.where(accept, out.y1, s.y)
    y_eval = s.y_eval
    if y_eval is not None:
        final = accept & last
        y_eval = _fill_eval(model, t_eval, s.t, s.y, t_new, y_new, final, args, y_eval, stepper)
    attempts = s.attempts
    if attempts is not None:
        err = jnp.sqrt(jnp.mean(jnp.where(error_mask, y_error, 0.0) ** 2))
        attempts = _log_attempt(attempts, s.n_attempts, s.t, h_try, accept, err, out.stats)
    if progress is not None:
        progress(t_new)
    rows = dict(
        ts=t_new,
        ys=y_new,
        hs=h_step,
        multipliers=out.multipliers,
        iterations=out.stats.iterations.astype(jnp.int32),
        residual_norms=out.stats.residual_norm,
        nonlinear_success=nonlinear_ok,
    )
    new = _LoopState(
        t=t_new,
        h=h_next,
        h_last=h_try,
        h_min=h_min,
        y=y_new,
        controller_state=controller_state,
        n_accepted=s.n_accepted + accept.astype(jnp.int32),
        n_rejected=s.n_rejected + (~accept).astype(jnp.int32),
        n_attempts=s.n_attempts + 1,
        n_iterations=s.n_iterations + out.stats.iterations.astype(jnp.int32),
        result=result,
        **{name: getattr(s, name) for name in _STEP_FIELDS},
        attempts=attempts,
        y_eval=y_eval,
    )
    return new, rows, accept


def _events(model, stepper, s, h_try, out, args, tolerance, error_mask):
    # `(violation, next_event, after_end)` of an attempt for the controller: a constraint
    # crossed without being enforced (in the units of `violation_scale` under the
    # controller's `tolerance`), and the predicted times to the next event (held exits
    # included) and to the first after the attempt's end (`StepInfo.event_after_end`);
    # none for a stepper that locates events itself.
    if stepper.locates_events:
        zero = jnp.zeros((), out.y1.dtype)
        none = jnp.full((), jnp.inf, out.y1.dtype)
        return zero, none, none
    t1 = s.t + h_try
    scale = None
    if tolerance is not None:
        # The controller's scale for the violation (`violation_scale`), which contacts
        # convert their penetration to.
        scale = violation_scale(*tolerance, s.y, error_mask)
    violation = model.violation(t1, h_try, s.y, out.y1, args, tolerance, scale)
    next_event = model.next_event(t1, h_try, s.y, out.y1, args)
    exit_violation, exit_time = model.held_exit(t1, h_try, s.y, out.y1, args)
    next_event = jnp.minimum(next_event, exit_time)
    after_end = next_event
    if model.projector.has_start_selection:
        # Only a relay's prediction tells the two apart (`ProjectionContext.after_end`).
        after_end = model.next_event(
            t1, h_try, s.y, out.y1, args, after_end=True, tolerance=tolerance
        )
        after_end = jnp.minimum(after_end, jnp.where(exit_time > h_try, exit_time, jnp.inf))
    return jnp.maximum(violation, exit_violation), next_event, after_end


def _fill_eval(model, t_eval, ta, ya, tb, yb, final, args, y_eval, stepper=None):
    # The states at the output times inside the accepted step [ta, tb), and at tb too on
    # the last step: the step `interpolate` picks for each time from saved steps, so both
    # give the same values (NaN stays where the run stopped before a time). A rejected
    # attempt has tb = ta (and is not final): it writes nothing.
    # The step's parts once (`_step_parts`), then each time's value from them; nothing
    # where no output time lies in the step (most attempts).
    span = jnp.where(tb > ta, tb - ta, 1.0)
    w = jnp.clip((t_eval - ta) / span, 0.0, 1.0)
    inside = (t_eval >= ta) & ((t_eval < tb) | final)

    def fill(y_eval):
        safe_tb = jnp.where(tb > ta, tb, ta + 1.0)
        p = _step_parts(model, ta, ya, safe_tb, yb, args)
        y = _values(model, p, t_eval, w, args, stepper, None)
        return jnp.where(inside[:, None], y, y_eval)

    return jax.lax.cond(jnp.any(inside), fill, lambda y_eval: y_eval, y_eval)


def finish(final: _LoopState, t1) -> Solution:
    """The [`nivpjax.Solution`][] of a loop state (after the loop, or after manual steps)."""
    result = RESULTS.where(
        (final.result == RESULTS.successful) & (final.t < t1),
        RESULTS.time_max_steps_reached,
        final.result,
    )
    k = final.n_accepted
    steps = _NO_STEPS if final.ts is None else _padded_steps(final, k)
    return Solution(
        **steps,
        t_final=final.t,
        h_last=final.h_last,
        y_final=final.y,
        n_accepted=k,
        n_rejected=final.n_rejected,
        n_iterations=final.n_iterations,
        result=result,
        y_eval=final.y_eval,
        attempts=_finish_attempts(final.attempts),
    )


def _padded_steps(final: _LoopState, k):
    # Padding rows repeat the last accepted state so that reductions and plots stay finite.
    # The other buffers hold their padding already (inf times; zero steps, counts and
    # residuals; success) in every row that no accepted step wrote.
    pad = jnp.arange(final.ts.shape[0]) > k
    return dict(
        ts=final.ts,
        ys=jnp.where(pad[:, None], final.ys[k], final.ys),
        hs=final.hs,
        multipliers=jnp.where(pad[:, None], final.multipliers[k], final.multipliers),
        iterations=final.iterations,
        residual_norms=final.residual_norms,
        nonlinear_success=final.nonlinear_success,
    )


def run(
    model: Model,
    stepper: AbstractStepper,
    controller: AbstractController,
    t0,
    t1,
    y0,
    args,
    h0,
    error_mask,
    max_steps: int,
    save_attempts: bool,
    kind: str,
    progress,
    checkpoints: int | None = None,
    save_steps: bool = True,
    t_eval=None,
) -> Solution:
    """The compiled loop. With `save_steps` the states at `t_eval` are left to
    `interpolate` (from the saved steps); without it they are filled in the loop."""
    state = init_state(
        model,
        stepper,
        controller,
        t0,
        t1,
        y0,
        args,
        h0,
        error_mask,
        max_steps,
        save_attempts,
        save_steps,
        t_eval,
    )

    def cond(s: _LoopState):
        return (s.t < t1) & (s.result == RESULTS.successful) & (s.n_attempts < max_steps)

    def body(s: _LoopState):
        return attempt(s, model, stepper, controller, t1, args, error_mask, progress, t_eval)

    if kind == "checkpointed" and stores_every_step(state, max_steps, checkpoints):
        return finish(
            _stored_run(
                cond,
                state,
                model,
                stepper,
                controller,
                t1,
                args,
                error_mask,
                progress,
                t_eval,
                max_steps,
            ),
            t1,
        )
    final = eqxi.while_loop(
        cond,
        body,
        state,
        max_steps=max_steps,
        buffers=_buffers if save_steps else None,
        kind=kind,
        checkpoints=checkpoints if kind == "checkpointed" else None,
    )
    return finish(final, t1)


def stores_every_step(state: _LoopState, max_steps: int, checkpoints: int | None) -> bool:
    """Whether reverse mode stores the loop state of every attempt (`_stored_loop`): with
    `checkpoints` of `max_steps` (clipped there), or by default (`None`) when the states
    fit `STORE_BUDGET_BYTES`. Not with `save_attempts` (its log is loop state)."""
    if state.attempts is not None:
        return False
    if checkpoints is not None:
        return checkpoints >= max_steps
    core = dataclasses.replace(state, **_NO_STEPS)
    return stored_bytes(core, max_steps) <= STORE_BUDGET_BYTES


def _stored_run(
    cond, state, model, stepper, controller, t1, args, error_mask, progress, t_eval, max_steps
) -> _LoopState:
    # The loop with every attempt's state stored for reverse mode; the saved-step buffers
    # are written by the loop from the rows each step returns.
    names = [name for name in _STEP_FIELDS if getattr(state, name) is not None]
    core = dataclasses.replace(state, **_NO_STEPS)

    def step(s: _LoopState):
        new, rows, accept = _advance(
            s, model, stepper, controller, t1, args, error_mask, progress, t_eval
        )
        return new, {name: rows[name] for name in names}, s.n_accepted + 1, accept

    buffers = {name: getattr(state, name) for name in names}
    final, buffers = stored_while_loop(cond, step, core, buffers, max_steps)
    return dataclasses.replace(final, **buffers)


def interpolate(sol: Solution, t_eval, model: Model | None = None, args=None, stepper=None):
    r"""The solution at `t_eval` from the accepted states; NaN after the point where the
    solve stopped (a failed run is flagged in `result`).

    Without `model`: piecewise linear. With it, each step is interpolated as the steppers
    start it (`Model.step_start`: the impacts closing at its start applied, the
    right-limit selections there), by the cubic Hermite interpolant of the two end states
    and rates (third order: local error $O(h^4)$; exact for a ball's parabola, whose
    steps event prediction makes long), linearly on algebraic rows (multipliers), except
    selection rows, which take the selection of their phase at `t`
    (`_held.selections_inside`: a sliding mode's equivalent control, split where the
    phase begins or ends inside the step). In a second-order sliding mode held across
    the step (super-twisting after its convergence) the state is moved onto the surface
    and its first derivative, $\sigma = \dot\sigma = 0$, which the steps keep
    (`_held.on_second_order_surface`).

    On rows a projector moves (`Model.rated_rows`), the rates are the ones the state
    takes (`Model.projected_rate`: zero normal motion where a set holds a row at a
    face, the vector field's where it is free, a friction law's reaction added), and
    every value is projected back into its set (`Model.project_rows`, the last
    operation: each output is the projector's value, inside a box bit for bit; not on a
    proximal map's rows, which no set constrains): a cubic between two points of a box
    can overshoot it.

    A phase that begins or ends inside a step is read off the rates at its ends, per row.
    A row free at the start and held at the end reached its face inside the step: it
    follows the free flow from the start (`_reached`: its rate the quadratic in $w$
    through the free rates at both ends and the rate's derivative at the start, third
    order), which the projection stops at the face where the flow reaches it, instead of
    a cubic bent to arrive there at the step's end ($O(h\,|f|)$ off). A row held at the
    start and free at the end left its face: it stays there until the free rate,
    interpolated linearly, turns away from the face, and follows the free flow back from
    the end after (`_left`). A friction row moving at the start and stuck at the end
    (zero projected rate) follows the flow from the start, held at the end's value from
    where it reaches it (`_stuck`). Models with impulses keep the rows a projector moves linear
    (a contact's velocity jumps inside a step, which no rate per end describes; a
    resting contact's force is not in the vector field).

    The quantities of a step alone (its start, the rates and their derivatives at both
    ends, the rows where a phase begins or ends, the held selection rows) are computed
    once per step (`_step_parts`); each output time adds its polynomial, the projection
    and the selections' equivalent control at its own state (`_values`).

    With `stepper`, a stepper that has its own continuous extension
    (`AbstractStepper.dense_output`: the event-driven stepper's, of order 4) gives the
    states inside the steps it vouches for.

    A step across which a switch happens (`Model.switch_jump`) interpolates from its start
    moved by the saltation term $(f^- - f^+)\,d\tau$, zero in value: the interpolant's
    derivatives then follow the post-switch branch, as the step's end does. Without it, a
    long step that begins just before a switch (event prediction lands there) would blend
    the pre- and post-switch sensitivities across the whole step."""
    k = sol.n_accepted
    idx = jnp.searchsorted(sol.ts, t_eval, side="right") - 1
    idx = jnp.clip(idx, 0, jnp.maximum(k - 1, 0))
    ta, tb = sol.ts[idx], sol.ts[jnp.minimum(idx + 1, k)]
    ya, yb = sol.ys[idx], sol.ys[jnp.minimum(idx + 1, k)]
    span = jnp.where(tb > ta, tb - ta, 1.0)
    w = jnp.clip((t_eval - ta) / span, 0.0, 1.0)
    if model is None:
        y = ya + w[:, None] * (yb - ya)
    else:
        y = _values(model, _parts_at(model, sol, idx, args), t_eval, w, args, stepper, 0)
    beyond = t_eval > sol.ts[k] * (1 + 1e-12) + 1e-300
    return jnp.where(beyond[:, None], jnp.nan, y)


# Steps whose parts `_parts_at` computes side by side (vmapped), per iteration.
PARTS_CHUNK = 16


def _parts_at(model: Model, sol: Solution, idx, args):
    # `_step_parts` of the steps `idx` (one per output time). Models with selection rows:
    # each distinct step's once, however many outputs it holds (their parts hold Newton
    # steps and Jacobians: 20 microseconds a step on the block in a friction cone), in
    # chunks of `PARTS_CHUNK` distinct steps in a scan, those beyond the last distinct
    # step skipped (`cond`: a select under `vmap`, where every chunk is computed). Other
    # models: per output time, all side by side (a few dozen operations, which one
    # vectorised pass does faster than a scan's iterations: measured, 0.09 against
    # 0.29 ms for 1000 outputs over the driven slider's 405 steps).
    k = sol.n_accepted

    def step(j):
        ta, tb = sol.ts[j], sol.ts[jnp.minimum(j + 1, k)]
        ya, yb = sol.ys[j], sol.ys[jnp.minimum(j + 1, k)]
        safe_tb = jnp.where(tb > ta, tb, ta + 1.0)  # a finished run's padding
        return _step_parts(model, ta, ya, safe_tb, yb, args)

    if not model.has_selections:
        return jax.vmap(step)(idx)
    n = idx.shape[0]
    rows = -(-n // PARTS_CHUNK) * PARTS_CHUNK
    order = jnp.sort(idx)
    first = jnp.concatenate([jnp.ones((1,), bool), order[1:] != order[:-1]])
    count = jnp.sum(first)
    # The distinct steps in increasing order, then the last one repeated.
    at = jnp.where(first, jnp.cumsum(first) - 1, rows)
    distinct = jnp.full((rows,), order[-1]).at[at].set(order, mode="drop")
    slot = jnp.searchsorted(distinct, idx, side="left")

    def chunk(i):
        js = jax.lax.dynamic_slice(distinct, (i * PARTS_CHUNK,), (PARTS_CHUNK,))
        return jax.vmap(step)(js)

    shapes = jax.eval_shape(chunk, 0)

    def skipped(i):
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    def body(carry, i):
        return carry, jax.lax.cond(i * PARTS_CHUNK < count, chunk, skipped, i)

    _, parts = jax.lax.scan(body, None, jnp.arange(rows // PARTS_CHUNK))
    return jax.tree.map(lambda a: a.reshape((rows,) + a.shape[2:])[slot], parts)


def _values(model: Model, p: dict, t, w, args, stepper, axis):
    # The states at the times `t` (fractions `w` of their steps; see `interpolate`: the
    # start as the steppers take it, impacts applied, right-limit selections, the
    # saltation shift of a switch inside; a stepper's own continuous extension where it
    # vouches for the step) from the steps' parts
    # (`_step_parts`; `axis` 0: one step per time, None: one step for all): what each
    # output time adds to the quantities of its step (polynomials, the projections, the
    # selections' equivalent control at the interpolated state). The second-order surface
    # correction only where a step holds such a mode (a select per time under `vmap`).
    def each(fn, *a):
        return jax.vmap(lambda p, *b: fn(model, p, *b, args), in_axes=(axis,) + (0,) * len(a))(
            p, *a
        )

    y = each(_base, t, w)
    if model.has_selections:
        y = jax.lax.cond(jnp.any(p["surface"]), lambda y: each(_on_surface, t, y), lambda y: y, y)
    y = each(_finish, t, y)
    if stepper is not None:
        own = each(lambda model, p, t, args: stepper.dense_output(model, t, *p["raw"], args), t)
        if own is not None:
            value, usable = own
            usable = jnp.reshape(usable, usable.shape + (1,) * (value.ndim - usable.ndim))
            y = jnp.where(usable, value, y)
    return y


def _base(model: Model, p: dict, t, w, args):
    # The value at the fraction w of the step with parts `p` before the second-order
    # surface, the projection and the selections (`_finish`).
    y0, y1, h = p["y0"], p["y1"], p["h"]
    linear = y0 + w * (y1 - y0)
    y = cubic_hermite(y0, y1, p["m0"], p["m1"], w)
    if not model.rated_rows.any():
        projected = jnp.asarray(model.projector.acts_on(y0.shape[0]))
        if model.has_selections:
            y = _stop(p["rest"], y0, y1, h, w, y)
        y = jnp.where(model.algebraic | projected, linear, y)
        if model.has_weighed:
            q = p["persistent"]
            y = jnp.where(q["rows"], cubic_hermite(y0, y1, q["m0"], q["m1"], w), y)
            y = _stop(q["stop"], y0, y1, h, w, y)
        return y
    r0, r1 = p["r0"], p["r1"]
    y = jnp.where(p["reached"], _reached(y0, r0, r1, p["da0"], h, w), y)
    y = jnp.where(p["left"], _left(y0, y1, r0, r1, p["da1"], h, w), y)
    if model.has_weighed:
        y = _stop(p["weighed"], y0, y1, h, w, y)
    if model.has_selections:
        y = _stop(p["rest"], y0, y1, h, w, y)
    return jnp.where(model.algebraic, linear, y)


def _finish(model: Model, p: dict, t, y, args):
    # The rows a set holds projected back into it (the rows it rates), then the selections.
    if model.rated_rows.any():
        y = model.project_rows(t, p["h"], y, model.held_rows, args)
    return _selections(model, p, t, y, args)


def _step_parts(model: Model, t0, y0, t1, y1, args) -> dict:
    # The quantities of the interpolant (see `interpolate`) that depend on the step alone,
    # computed once for all the output times inside it: the start as the steppers take it,
    # the slopes at both ends, the rows where a phase begins or ends and the rates'
    # derivatives there, the held selection rows. `raw`: the saved step, for a stepper's
    # own continuous extension.
    raw = (t0, y0, t1, y1)
    h = t1 - t0
    y0, f0, _ = model.step_start(t0, h, y0, args)
    y0 = y0 + model.switch_jump(t0, y0, t1, y1, args)
    f1 = model.f(t1, y1, args)
    if model.has_selections:
        # The phase's selections at the end as at the start (`Model.step_start`): a held
        # row's equivalent control, not the stage's value (an average over the step where
        # a stick begins inside it); a second-order sliding mode's at both ends.
        end = held_start(model, t1, h, y1, args)
        ends0, ends1 = second_order_ends(model, t0, y0, t1, end, args)
        f0, f1 = model.f(t0, ends0, args), model.f(t1, ends1, args)
    r0, r1 = model.to_state(f0), model.to_state(f1)
    p = dict(raw=raw, t0=t0, y0=y0, t1=t1, y1=y1, h=h, r0=r0, r1=r1)
    if model.has_selections:
        p["surface"] = second_order_rows(model, t0, y0, t1, y1, args)
        p["phases"] = selection_phases(model, t0, y0, t1, y1, args)
    if not model.rated_rows.any():
        p["m0"], p["m1"] = h * r0, h * r1
        if model.has_selections:
            p["rest"] = _come_to_rest(model, t0, y0, t1, y1, r0, r1, args, True)
        if model.has_weighed:
            p["persistent"] = _persistent(model, t0, y0, f0, t1, y1, f1, h, args)
        return p
    p0, held0 = model.projected_rate(t0, h, y0, f0, args)
    p1, held1 = model.projected_rate(t1, h, y1, f1, args)
    sets = model.held_rows
    p["m0"], p["m1"] = h * p0, h * p1
    p["reached"] = sets & ~held0 & held1
    p["left"] = sets & held0 & ~held1
    p["da0"] = h * _rate_change(model, t0, y0, r0, args)
    p["da1"] = h * _rate_change(model, t1, y1, r1, args)
    if model.has_weighed:
        # Held: zero rate up to the round-off of the law's reaction cancelling f.
        p["weighed"] = _stopped_inside(model, t0, y0, p0, p1, r1, model.weighed, h, args)
    if model.has_selections:
        free = ~sets & ~model.weighed  # rows the cases above leave to the cubic
        p["rest"] = _come_to_rest(model, t0, y0, t1, y1, r0, r1, args, free)
    return p


def _come_to_rest(model: Model, t0, y0, t1, y1, r0, r1, args, rows):
    # A phase that begins inside the step and holds a differential row still at its end
    # (a block stopped by cone friction, a relay's state reaching its sliding surface):
    # the row moving at the start and at rest at the end follows the flow from the start
    # (second order, the selections held), held at the end's value from where it reaches
    # it (`_stuck`), instead of a cubic bent to arrive there with zero rate over the whole
    # step (measured: the trapezoidal rule's block on a plane, 129 times further off at
    # `t_eval` than the steps, still moving after its stop). The step's part (`_stop`
    # applies it).
    rows = rows & ~model.algebraic & phase_begins(model, t0, y0, t1, y1, args)
    moving = jnp.where(model.algebraic, 0.0, r0)
    return _stopped_inside(model, t0, y0, moving, r1, r1, rows, t1 - t0, args)


def _stopped_inside(model: Model, t0, y0, p0, p1, scale, rows, h, args):
    # `(stopped, p0, da0)` of `_stuck` on the rows among `rows` moving at the start (rate
    # `p0`) and at rest at the end (`p1` zero up to round-off relative to |p0| + |scale|),
    # `_stop` applies it. Serves friction rows held at the end, persistent contacts' rows
    # and rows a phase that begins inside the step brings to rest.
    small = jnp.sqrt(jnp.finfo(y0.dtype).eps) * (jnp.abs(p0) + jnp.abs(scale))
    stopped = rows & (jnp.abs(p0) > small) & (jnp.abs(p1) <= small)
    da0 = h * _rate_change(model, t0, y0, p0, args)
    return stopped, p0, da0


def _stop(part, y0, y1, h, w, y):
    # `_stuck` where the step's part (`_stopped_inside`) says a row stopped; `y` elsewhere.
    stopped, p0, da0 = part
    return jnp.where(stopped, _stuck(y0, y1, p0, da0, h, w), y)


def _on_surface(model: Model, p, t, y, args):
    # A second-order sliding mode held across the step: the differential state moved onto
    # the surface's first derivative (`_held.on_second_order_surface`).
    if not model.has_selections:
        return y
    t0, y0, t1, y1 = p["t0"], p["y0"], p["t1"], p["y1"]
    return on_second_order_surface(model, t, t0, y0, t1, y1, y, args, p["surface"])


def _selections(model: Model, p, t, y, args):
    # The selection rows (a relay's w) by the phase they are in at t (see
    # `_held.selections_inside`); linear where the model has none.
    if not model.has_selections:
        return y
    t0, y0, t1, y1 = p["t0"], p["y0"], p["t1"], p["y1"]
    return selections_inside(model, t, t0, y0, t1, y1, y, args, p["phases"])


def interpolate_multipliers(sol: Solution, t_eval, y_eval, model: Model, args=None):
    r"""The constraint reactions at `t_eval` (units of $f$: a force, per unit mass where
    $f$ is an acceleration), each inside its set, from the states `y_eval` that
    `interpolate` gives there; NaN where `y_eval` is.

    The reaction the interpolated state takes (`Model.reaction_at`): it inherits the
    states' piecewise rule, so a phase that begins or ends inside a step splits it where
    the states do (a face reached, a stick reached: the reaction is zero, or the law's
    slip value, up to the instant the state arrives) and follows the stepper's order
    elsewhere (a friction force in slip at the interpolated state; a box's normal force
    $-f$ at the interpolated time). Contacts: zero in flight, the resting force where a
    contact holds the body; an impact is an impulse, which no force at an instant
    describes (the `multipliers` buffer's row of that step holds impulse / h)."""
    if sol.ts is None:
        # Steps not saved: the last step's size (it only sets the JVP's point).
        h = jnp.broadcast_to(sol.h_last, t_eval.shape)
    else:
        k = sol.n_accepted
        idx = jnp.searchsorted(sol.ts, t_eval, side="right") - 1
        idx = jnp.clip(idx, 0, jnp.maximum(k - 1, 0))
        span = sol.ts[jnp.minimum(idx + 1, k)] - sol.ts[idx]
        h = jnp.where(span > 0, span, 1.0)
    safe_y = jnp.where(jnp.isfinite(y_eval), y_eval, 0.0)
    out = jax.vmap(lambda t, h, y: model.reaction_at(t, h, y, args))(t_eval, h, safe_y)
    return jnp.where(jnp.isnan(y_eval), jnp.nan, out)


def _persistent(model: Model, t0, y0, f0, t1, y1, f1, h, args):
    # Models with impulses, on the weighed rows whose law's reaction acts at both ends (a
    # contact pressed by the flow at both ends, its friction): no impulse in the step (an
    # impact starts from a contact that is not pressed), so the cubic Hermite with the
    # law's rates f + r, and a stick reached inside the step as on friction rows
    # (`_stuck`). Elsewhere the value is kept (linear on the rows a projector moves). The
    # step's part: the rows, the slopes and the stop.
    law0 = model.law_reaction(t0, h, y0, f0, args)
    law1 = model.law_reaction(t1, h, y1, f1, args)
    p0, p1 = model.to_state(f0 + law0), model.to_state(f1 + law1)
    rows = model.weighed & (law0 != 0) & (law1 != 0)
    stopped, p0, da0 = _stopped_inside(model, t0, y0, p0, p1, model.to_state(f1), rows, h, args)
    # A turn located at the step's end (a friction reversal: the weighed rows' values at
    # rest there, moving at the start): the law's end rate is the turn's far side (at
    # rest, the reaction opposes the coming motion), a slope the step never had. The rows
    # follow the flow from the start, as into a stick (measured: a ball turning back on
    # an elliptic bowl's wall, Bathe, 3.1x further off at `t_eval` than the steps).
    small = jnp.sqrt(jnp.finfo(y0.dtype).eps) * (jnp.abs(y0) + h * jnp.abs(p0))
    turned = rows & (jnp.abs(y1) <= small) & (jnp.abs(y0) > small)
    return dict(rows=rows, m0=h * p0, m1=h * p1, stop=(stopped | turned, p0, da0))


def _rate_change(model: Model, t, y, rate, args):
    # The derivative of the free rate along the flow at (t, y), state units.
    field = lambda tt, yy: model.f(tt, yy, args)  # noqa: E731
    return model.to_state(jax.jvp(field, (t, y), (jnp.ones_like(t), rate))[1])


def _reached(y0, r0, r1, da0, h, w):
    # A face reached inside the step: the free flow from the start, its rate the quadratic
    # in w with the free rates at both ends and the rate's derivative `da0` (times h) at
    # the start (third order), which the projection stops at the face.
    c = r1 - r0 - da0
    return y0 + h * w * (r0 + w * (0.5 * da0 + w * c / 3))


def _stuck(y0, y1, p0, da0, h, w):
    # A stick reached inside the step (a friction row moving at the start, held at the
    # end): the flow from the start (second order: the reaction's own change is not in
    # `da0`), held at the end's value from where it reaches it, instead of a cubic bent to
    # arrive there with the stick's zero rate.
    flow = y0 + h * w * (p0 + 0.5 * w * da0)
    return jnp.clip(flow, jnp.minimum(y0, y1), jnp.maximum(y0, y1))


def _left(y0, y1, r0, r1, da1, h, w):
    # A face left inside the step: held at the start's value until the free rate,
    # interpolated linearly between the ends, turns from pushing into the face (r0) to
    # leaving it (r1); after that the free flow back from the end (its rate the quadratic
    # with the free rates at both ends and the derivative `da1` at the end). Where the
    # rates do not change sign, the flow back throughout (the projection holds it).
    turns = r0 * r1 < 0
    w_leave = jnp.where(turns, r0 / jnp.where(turns, r0 - r1, 1.0), 0.0)
    v = w - 1
    c = r0 - r1 + da1
    back = y1 + h * v * (r1 + v * (0.5 * da1 + v * c / 3))
    return jnp.where(w < w_leave, y0, back)
