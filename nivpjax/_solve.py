"""`solve`: validate, assemble, run the compiled loop, build the `Solution`."""

import contextvars
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import _validate as v
from ._cache import CachedJit
from ._controller import AbstractController
from ._loop import interpolate, interpolate_multipliers, run
from ._model import Model
from ._progress_meter import progress_callback
from ._projector import AbstractProjector
from ._results import RESULTS
from ._saveat import SaveAt, resolve as resolve_saveat
from ._solution import Solution
from ._stepper import AbstractStepper


# Whether a solve traced under a transformation checks its traced inputs in the program (a
# finite `y0`, `t1 > t0`: failure codes in `Solution.result`, raised by `throw`).
# `solve_batched` checks its concrete inputs itself and turns this off.
_IN_GRAPH_CHECKS: contextvars.ContextVar[bool] = contextvars.ContextVar(
    "nivpjax_in_graph_checks", default=True
)


class SolveError(RuntimeError):
    """Raised by [`nivpjax.solve`][] with `throw=True` when the run failed."""


def solve(
    vector_field,
    t0,
    t1,
    y0,
    args: Any = None,
    *,
    projector: AbstractProjector | None = None,
    mass_matrix=None,
    stepper: AbstractStepper | None = None,
    controller: AbstractController | None = None,
    h0=None,
    t_eval=None,
    saveat: SaveAt | None = None,
    max_steps: int = 4096,
    error_estimate: Literal["auto", "embedded", "richardson"] = "auto",
    tau=1.0,
    equation_rows=None,
    save_attempts: bool = False,
    adjoint: Literal["checkpointed", "forward"] = "checkpointed",
    checkpoints: int | None = None,
    progress: bool = False,
    throw: bool = True,
) -> Solution:
    r"""Integrate $A y' = f(t, y, \text{args})$, with the nonsmooth rule encoded by
    `projector`, from `t0` to `t1`.

    Every stage of every step solves the variational inequality $y = P(y - \rho R(y))$ with
    the stepper's nonlinear solver. The whole loop is one compiled program: `jax.jit`,
    `jax.vmap` (over `y0`, `args`, `t1`, ...) and reverse-mode `jax.grad` work through it.

    **Arguments:**

    - `vector_field`: $f(t, y, \text{args})$ returning an array shaped like `y0`.
    - `t0`, `t1`: the interval, `t1 > t0`.
    - `y0`: the initial state, a 1-D floating array (float32 or float64). With algebraic
      rows, the multipliers in `y0` are only initial guesses: consistent values are solved
      for at `t0` (differential states held fixed) before the first step.
    - `args`: any pytree of parameters, passed to $f$ and to callable bounds of projectors.
    - `projector`: an [`nivpjax.AbstractProjector`][]; default [`nivpjax.Identity`][].
    - `mass_matrix`: the constant descriptor matrix $A$ (concrete, shape `(n, n)`); zero
      rows are algebraic. Default: the identity.
    - `stepper`: default [`nivpjax.Bathe`][] with [`nivpjax.SemismoothNewton`][].
    - `controller`: default [`nivpjax.PIDController`][]`(rtol=1e-3, atol=1e-6)`; use
      [`nivpjax.ConstantStepSize`][] with `h0` for fixed steps.
    - `h0`: the initial step (estimated if `None` and the controller is adaptive).
    - `t_eval`: optional output times in $[t_0, t_1]$; the solution there is interpolated
      into `Solution.y_eval`: cubic Hermite on differential rows, from each step's start as
      the stepper took it, with the projected rates on rows a set constrains and each value
      projected back into its set; selections (a relay's $w$) by the phase they are in,
      other algebraic rows linear (see `nivpjax._loop.interpolate` and the error-control
      page). The constraint reactions there go into `Solution.multipliers_eval`.
    - `saveat`: what to keep, a [`nivpjax.SaveAt`][]; default `SaveAt(steps=True)`: every
      accepted step (and the states at `t_eval` if given). `SaveAt()` keeps only the final
      state, `SaveAt(ts=...)` (or `SaveAt()` with `t_eval`) the final state and the states
      at those times: the per-step buffers are then not allocated, which is what a
      `jax.vmap` sweep wants. Times are given once, as `t_eval` or as `saveat.ts`.
    - `max_steps`: bound on attempted steps; saved steps' buffers have `max_steps + 1` rows.
    - `error_estimate`: `"auto"` uses the stepper's embedded estimate when it has one and
      Richardson step doubling otherwise; `"richardson"` forces step doubling.
    - `tau`, `equation_rows`: scaling of algebraic rows (see [`nivpjax.Model`][]); `tau` is
      a positive scalar or one value per component, `equation_rows` a boolean mask.
    - `save_attempts`: record every attempted step in `Solution.attempts`.
    - `adjoint`: `"checkpointed"` (default) supports reverse-mode differentiation;
      `"forward"` uses a plain `lax.while_loop` (forward mode only, a little faster).
    - `checkpoints`: with `adjoint="checkpointed"`, how many loop states reverse mode may
      store (`None` or a positive int). `None` (default): every attempted step, when
      `max_steps` copies of the loop state (time, step sizes, state vector, controller
      state; not the output buffers) fit in 64 MiB (per batch member under `vmap`). The
      forward pass then stores, per attempt, the residuals of the step's VJP (or, when
      those exceed 64 MiB in all, the loop state, linearised again on the way back;
      `nivpjax._stored_loop`), and reverse mode recomputes no step. When they do not
      fit, equinox's online Stumm–Walther checkpointing with
      $O(\sqrt{\text{max\_steps}})$ checkpoints (90 for `max_steps=4096`), which
      recomputes steps from the stored ones. A value of at least `max_steps` (larger
      values are clipped to it) stores every step whatever the memory; a smaller value
      selects equinox's checkpointing with that many, which suits a `jax.vmap` of many
      gradients (the default's storage, allocated up front, is per member, e.g. 5.8 MB
      for the default ball and 14.6 MB for the relay at `max_steps=4096`). Values and
      gradients do not depend on it (up to round-off); only the cost of reverse mode
      does. Under `jax.grad`, the solve's reverse mode
      runs two cached programs of its own (the forward pass with the stored values,
      and the backward pass), compiled with `nj.compiler_options()` when the gradient
      is taken at top level: a second gradient of the same structure compiles nothing.
    - `progress`: print a progress bar to stderr.
    - `throw`: raise [`nivpjax.SolveError`][] if the run failed (`max_steps` reached, step
      size below `h_min`, repeated nonlinear failures). With `False` the failure is only in
      `Solution.result` (per member under `vmap`). Under `jit`/`vmap` the error is raised
      through `equinox.error_if`.

    **Returns:** a [`nivpjax.Solution`][].

    **Raises:** `ValueError`/`TypeError` for bad input, before any work. Inputs traced by
    an outer transformation (`y0`, `t0`, `t1` under `jit`) are checked inside the program
    instead: a non-finite `y0` or `t1 <= t0` ends the run at once with
    `RESULTS.nonfinite_y0` or `RESULTS.empty_span` (raised with `throw=True`).
    """
    y0 = v.check_y0(y0)
    n = y0.shape[0]
    dtype = y0.dtype
    t0_c, t1_c = v.check_times(t0, t1)
    max_steps = v.check_max_steps(max_steps)
    projector, stepper, controller = v.check_components(projector, stepper, controller, n)
    checkpoints = v.check_modes(error_estimate, adjoint, checkpoints, max_steps)
    if checkpoints is None and adjoint == "checkpointed" and v.is_batched((y0, t0, t1, args)):
        # Under `vmap` the stored loop's rows would be allocated per member (MBs each):
        # equinox's checkpoints instead, as a `checkpoints` below `max_steps` asks.
        checkpoints = v.equinox_checkpoints(max_steps)
    tau_arr = v.check_tau(tau, n)
    equation_rows = v.check_equation_rows(equation_rows, n)
    v.check_step_bounds(controller, h0)
    stepper = v.error_stepper(stepper, controller, error_estimate)
    mass, algebraic = v.check_mass_matrix(mass_matrix, n, dtype)
    # NumPy where concrete: `jit` transfers them on its fast path (a `jnp.asarray` each
    # would cost a dispatch).
    t0 = v.as_array(t0, dtype)
    t1 = v.as_array(t1, dtype)
    error_mask = v.check_error_mask(controller, algebraic, n)
    save_steps, t_eval = resolve_saveat(saveat, t_eval)
    t_eval = v.check_t_eval(t_eval, dtype, t0_c, t1_c)
    model = Model.build(
        vector_field,
        projector,
        mass,
        algebraic,
        tau=float(tau_arr) if tau_arr.shape == () else jnp.asarray(tau_arr, dtype),
        equation_rows=equation_rows,
    )
    stepper.validate_model(model)
    traced = v.is_traced((y0, t0, t1, args, t_eval, h0))
    call = _solve_jit.prepare(
        model,
        stepper,
        controller,
        t0,
        t1,
        y0,
        args,
        h0,
        error_mask,
        t_eval,
        max_steps,
        save_attempts,
        save_steps,
        v.ADJOINTS[adjoint],
        checkpoints,
        progress,
        throw and traced,
        traced and _IN_GRAPH_CHECKS.get(),
    )
    if not call.known:  # traces the user's function: only for a new structure or new types
        v.check_vector_field(vector_field, t0, y0, args)
    # Reverse mode through the checkpointed adjoint runs compiled programs of its own
    # (`CachedJit.call_with_vjp`): cached, and with nivpjax's compiler options under a
    # top-level `jax.grad`.
    sol = call.with_vjp() if adjoint == "checkpointed" else call()
    if throw and not traced:
        sol = _raise_if_failed(sol)
    return sol


def _solve_impl(
    model,
    stepper,
    controller,
    t0,
    t1,
    y0,
    args,
    h0,
    error_mask,
    t_eval,
    max_steps,
    save_attempts,
    save_steps,
    kind,
    checkpoints,
    progress,
    throw_inside,
    check_inside,
):
    meter = progress_callback(t0, t1) if progress else None
    sol = run(
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
        kind,
        meter,
        checkpoints,
        save_steps,
        t_eval,
    )
    if t_eval is not None:
        # Without saved steps the loop filled `y_eval` itself.
        y_eval = interpolate(sol, t_eval, model, args, stepper) if save_steps else sol.y_eval
        multipliers_eval = interpolate_multipliers(sol, t_eval, y_eval, model, args)
        sol = eqx.tree_at(
            lambda s: (s.t_eval, s.y_eval, s.multipliers_eval),
            sol,
            (t_eval, y_eval, multipliers_eval),
            is_leaf=lambda x: x is None,
        )
    if check_inside:  # concrete inputs were checked before the call
        sol = _checked_inputs(sol, y0, t0, t1)
    if throw_inside:
        sol = _error_if_failed(sol)
    return sol


_solve_jit = CachedJit(_solve_impl)


def _checked_inputs(sol: Solution, y0, t0, t1) -> Solution:
    # Traced inputs are checked in the program as failure codes, not as host callbacks
    # (`equinox.error_if`): JAX's persistent cache does not store a program that holds a
    # callback, so every jitted solve recompiled in every process, `throw=False` or not.
    # The run itself goes ahead (with `t1 <= t0` the loop does not start; a NaN `y0`
    # fails in its first steps); its outputs are meaningless, as the result says.
    result = RESULTS.where(jnp.all(jnp.isfinite(y0)), sol.result, RESULTS.nonfinite_y0)
    result = RESULTS.where(t1 > t0, result, RESULTS.empty_span)
    return eqx.tree_at(lambda s: s.result, sol, result)


def _error_if_failed(sol: Solution) -> Solution:
    # The failure check inside a traced program: raises when the program runs.
    return sol.result.error_if(sol, sol.result != RESULTS.successful)


def _raise_if_failed(sol: Solution) -> Solution:
    result = sol.result
    if isinstance(result._value, jax.core.Tracer):
        # Under an outer transformation that none of the arguments showed (a closure over
        # a traced value, or constants only inside an outer `jit`): check in its graph.
        return _error_if_failed(sol)
    if np.ndim(result._value) != 0:
        failed = np.flatnonzero(np.asarray(result._value) != RESULTS.successful._value)
        if failed.size:
            raise SolveError(
                f"{failed.size} batch member(s) failed (indices {failed[:10].tolist()}"
                f"{'...' if failed.size > 10 else ''}); pass throw=False and inspect "
                "`Solution.result` per member."
            )
        return sol
    if int(np.asarray(result._value)) == int(RESULTS.successful._value):
        return sol
    k = int(sol.n_accepted)
    t = float(sol.t_final)
    h = float(sol.h_last)
    message = RESULTS[result]
    raise SolveError(
        f"nivpjax.solve failed at t = {t:.10g} after {k} accepted and "
        f"{int(sol.n_rejected)} rejected steps (last attempted step size {h:.3g}): {message}"
    )
