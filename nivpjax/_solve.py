"""`solve`: validate, assemble, run the compiled loop, build the `Solution`."""

import math
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._controller import AbstractController, PIDController
from ._loop import interpolate, run
from ._model import Model
from ._progress_meter import progress_callback
from ._projector import AbstractProjector, Identity
from ._results import RESULTS
from ._solution import Solution
from ._stepper import AbstractStepper, Bathe, Richardson


class SolveError(RuntimeError):
    """Raised by [`nivpjax.solve`][] with `throw=True` when the run failed."""


def _is_traced(x) -> bool:
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x))


def _concrete_float(name, value):
    if _is_traced(value):
        return None
    arr = np.asarray(value)
    if arr.shape != ():
        raise ValueError(f"`{name}` must be a scalar, got shape {arr.shape}.")
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise TypeError(f"`{name}` must be a real number, got {value!r}.")
    out = float(arr)
    if not math.isfinite(out):
        raise ValueError(f"`{name}` must be finite, got {out}.")
    return out


def _check_y0(y0):
    if isinstance(y0, (list, tuple)):
        y0 = np.asarray(y0, dtype=float)
    if not hasattr(y0, "shape") or not hasattr(y0, "dtype"):
        raise TypeError(f"`y0` must be an array, got {type(y0).__name__}.")
    if y0.ndim != 1:
        raise ValueError(f"`y0` must be a 1-D array of shape (n,), got shape {y0.shape}.")
    if y0.shape[0] == 0:
        raise ValueError("`y0` must have at least one component.")
    if not jnp.issubdtype(y0.dtype, jnp.floating):
        raise TypeError(
            f"`y0` must have a floating dtype (float32 or float64), got {y0.dtype}. "
            "Convert it, e.g. `jnp.asarray(y0, float)`."
        )
    if not _is_traced(y0) and not np.all(np.isfinite(np.asarray(y0))):
        bad = np.flatnonzero(~np.isfinite(np.asarray(y0))).tolist()
        raise ValueError(f"`y0` contains NaN or inf at components {bad}.")
    return jnp.asarray(y0)


def _check_mass_matrix(mass_matrix, n, dtype):
    if mass_matrix is None:
        return None, np.zeros(n, bool)
    if _is_traced(mass_matrix):
        raise TypeError(
            "`mass_matrix` must be a concrete array (its zero rows decide which rows are "
            "algebraic at trace time); pass it outside `jit`/`vmap` or close over it."
        )
    try:
        A = np.asarray(mass_matrix, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(
            f"`mass_matrix` must be a numeric (n, n) array, got {mass_matrix!r}."
        ) from None
    if A.shape != (n, n):
        raise ValueError(
            f"`mass_matrix` must have shape (n, n) = ({n}, {n}) to match `y0`, got {A.shape}."
        )
    if not np.all(np.isfinite(A)):
        raise ValueError("`mass_matrix` contains NaN or inf.")
    algebraic = np.all(A == 0, axis=1)
    if np.array_equal(A, np.eye(n)):
        return None, algebraic
    return jnp.asarray(A, dtype), algebraic


def _check_vector_field(vector_field, t0, y0, args):
    if not callable(vector_field):
        raise TypeError(f"`vector_field` must be callable f(t, y, args), got {vector_field!r}.")
    try:
        out = jax.eval_shape(vector_field, t0, y0, args)
    except TypeError as err:
        if "positional argument" not in str(err):
            raise
        raise TypeError(
            f"`vector_field` must accept (t, y, args) (diffrax's convention); calling it "
            f"failed with: {err}"
        ) from None
    shape = getattr(out, "shape", None)
    if shape != y0.shape:
        raise ValueError(
            f"`vector_field(t, y, args)` must return an array of the same shape as `y0` "
            f"{y0.shape}, got {shape if shape is not None else type(out).__name__}."
        )


_ADJOINTS = {"checkpointed": "checkpointed", "forward": "lax"}


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
      (piecewise linear) into `Solution.y_eval`.
    - `max_steps`: bound on attempted steps; buffers have `max_steps + 1` rows.
    - `error_estimate`: `"auto"` uses the stepper's embedded estimate when it has one and
      Richardson step doubling otherwise; `"richardson"` forces step doubling.
    - `tau`, `equation_rows`: scaling of algebraic rows (see [`nivpjax.Model`][]); `tau` is
      a positive scalar or one value per component, `equation_rows` a boolean mask.
    - `save_attempts`: record every attempted step in `Solution.attempts`.
    - `adjoint`: `"checkpointed"` (default) supports reverse-mode differentiation;
      `"forward"` uses a plain `lax.while_loop` (forward mode only, a little faster).
    - `checkpoints`: with `adjoint="checkpointed"`, how many loop states reverse mode may
      store (`None` or a positive int). `None` (default) lets equinox choose
      $O(\sqrt{\text{max\_steps}})$ (90 for `max_steps=4096`); a run that attempts more
      steps than there are checkpoints recomputes steps from the stored ones (online
      Stumm–Walther checkpointing). A value of at least
      `max_steps` (larger values are clipped to it) stores every attempted step: nothing is
      recomputed and equinox skips the checkpoint schedule, typically the fastest reverse
      mode (`benchmarks/gradients.py`: value_and_grad 2.6–3.1x the forward solve instead
      of 4.6–5.6x), for `max_steps` copies of the loop state (time, step sizes, state
      vector, controller state; not the output buffers), allocated up front (per batch
      member under `vmap`). Values and gradients do not depend on it (up to round-off);
      only the cost of reverse mode does.
    - `progress`: print a progress bar to stderr.
    - `throw`: raise [`nivpjax.SolveError`][] if the run failed (`max_steps` reached, step
      size below `h_min`, repeated nonlinear failures). With `False` the failure is only in
      `Solution.result` (per member under `vmap`). Under `jit`/`vmap` the error is raised
      through `equinox.error_if`.

    **Returns:** a [`nivpjax.Solution`][].

    **Raises:** `ValueError`/`TypeError` for bad input, before any work.
    """
    y0 = _check_y0(y0)
    n = y0.shape[0]
    dtype = y0.dtype
    t0_c = _concrete_float("t0", t0)
    t1_c = _concrete_float("t1", t1)
    if t0_c is not None and t1_c is not None and not t1_c > t0_c:
        raise ValueError(f"`t1` must be greater than `t0`, got t0={t0_c}, t1={t1_c}.")
    if (
        not isinstance(max_steps, (int, np.integer))
        or isinstance(max_steps, (bool, np.bool_))
        or max_steps < 1
    ):
        raise ValueError(f"`max_steps` must be a positive int, got {max_steps!r}.")
    max_steps = int(max_steps)
    if projector is None:
        projector = Identity()
    if not isinstance(projector, AbstractProjector):
        raise TypeError(f"`projector` must be an AbstractProjector, got {projector!r}.")
    projector.validate(n)
    if stepper is None:
        stepper = Bathe()
    if not isinstance(stepper, AbstractStepper):
        raise TypeError(
            f"`stepper` must be an AbstractStepper (e.g. nivpjax.BackwardEuler()), got {stepper!r}."
        )
    if controller is None:
        controller = PIDController()
    if not isinstance(controller, AbstractController):
        raise TypeError(f"`controller` must be an AbstractController, got {controller!r}.")
    if error_estimate not in ("auto", "embedded", "richardson"):
        raise ValueError(
            "`error_estimate` must be one of 'auto', 'embedded', 'richardson', got "
            f"{error_estimate!r}."
        )
    if adjoint not in _ADJOINTS:
        raise ValueError(f"`adjoint` must be 'checkpointed' or 'forward', got {adjoint!r}.")
    if checkpoints is not None:
        if not isinstance(checkpoints, (int, np.integer)) or isinstance(
            checkpoints, (bool, np.bool_)
        ):
            raise TypeError(f"`checkpoints` must be a positive int or None, got {checkpoints!r}.")
        if checkpoints < 1:
            raise ValueError(f"`checkpoints` must be a positive int or None, got {checkpoints!r}.")
        if adjoint != "checkpointed":
            raise ValueError(
                f"`checkpoints` only applies to adjoint='checkpointed', got adjoint={adjoint!r}."
            )
        checkpoints = min(int(checkpoints), max_steps)
    if (
        isinstance(tau, (str, bytes))
        or not np.issubdtype(np.asarray(tau).dtype, np.number)
        or np.iscomplexobj(tau)
    ):
        raise TypeError(f"`tau` must be a positive number or array, got {tau!r}.")
    tau_arr = np.asarray(tau, dtype=float)
    if tau_arr.shape not in ((), (n,)) or not np.all(np.isfinite(tau_arr) & (tau_arr > 0)):
        raise ValueError(
            f"`tau` must be a positive finite scalar or an array of shape ({n},), got {tau!r}."
        )
    if equation_rows is not None:
        equation_rows = np.asarray(equation_rows, bool)
        if equation_rows.shape != (n,):
            raise ValueError(
                f"`equation_rows` must be a boolean array of shape ({n},), got "
                f"{equation_rows.shape}."
            )
        equation_rows = jnp.asarray(equation_rows)
    if h0 is not None:
        h0_c = _concrete_float("h0", h0)
        if h0_c is not None and not h0_c > 0:
            raise ValueError(f"`h0` must be positive, got {h0_c}.")
    h_min, h_max = controller.bounds
    if h_min is not None and not (math.isfinite(h_min) and h_min >= 0):
        raise ValueError(f"`h_min` must be finite and non-negative, got {h_min}.")
    if h_max is not None and not (math.isfinite(h_max) and h_max > 0):
        raise ValueError(f"`h_max` must be finite and positive, got {h_max}.")
    if h0 is None and controller.requires_h0:
        raise ValueError(f"{type(controller).__name__} needs an initial step `h0`.")
    if h_min is not None and h_max is not None and h_min > h_max:
        raise ValueError(f"`h_min` must not exceed `h_max`, got {h_min} > {h_max}.")

    if controller.needs_error_estimate:
        if error_estimate == "embedded" and stepper.error_order == 0:
            raise ValueError(
                f"{type(stepper).__name__} has no embedded error estimate; use "
                "error_estimate='richardson' or 'auto', or nivpjax.EmbeddedBETR."
            )
        if error_estimate == "richardson" or stepper.error_order == 0:
            stepper = Richardson(stepper)

    mass, algebraic = _check_mass_matrix(mass_matrix, n, dtype)
    t0 = jnp.asarray(t0, dtype)
    t1 = jnp.asarray(t1, dtype)
    _check_vector_field(vector_field, t0, y0, args)
    error_mask = getattr(controller, "error_mask", None)
    if error_mask is None:
        error_mask = ~algebraic
    else:
        error_mask = np.asarray(error_mask, bool)
        if error_mask.shape != (n,):
            raise ValueError(
                f"`error_mask` must be a boolean array of shape ({n},), got {error_mask.shape}."
            )
    if t_eval is not None:
        if not _is_traced(t_eval) and (
            isinstance(t_eval, (str, bytes))
            or not np.issubdtype(np.asarray(t_eval).dtype, np.number)
            or np.iscomplexobj(t_eval)
        ):
            raise TypeError(f"`t_eval` must be an array of real times, got {t_eval!r}.")
        t_eval = jnp.atleast_1d(jnp.asarray(t_eval, dtype))
        if t_eval.ndim != 1:
            raise ValueError(f"`t_eval` must be 1-D, got shape {t_eval.shape}.")
        if not _is_traced(t_eval) and t0_c is not None and t1_c is not None:
            te = np.asarray(t_eval)
            if not np.all(np.isfinite(te)):
                raise ValueError("`t_eval` contains NaN or inf.")
            if np.any(np.diff(te) < 0):
                raise ValueError("`t_eval` must be sorted in increasing order.")
            if te.min() < t0_c or te.max() > t1_c:
                raise ValueError(
                    f"`t_eval` must lie within [t0, t1] = [{t0_c}, {t1_c}], got values in "
                    f"[{te.min()}, {te.max()}]."
                )

    model = Model(
        vector_field=vector_field,
        projector=projector,
        mass_matrix=mass,
        algebraic=jnp.asarray(algebraic),
        tau=float(tau_arr) if tau_arr.shape == () else jnp.asarray(tau_arr, dtype),
        equation_rows=equation_rows,
        has_algebraic=bool(algebraic.any()),
    )
    traced = _is_traced((y0, t0, t1, args, t_eval, h0))
    sol = _solve_jit(
        model,
        stepper,
        controller,
        t0,
        t1,
        y0,
        args,
        h0,
        jnp.asarray(error_mask),
        t_eval,
        max_steps,
        save_attempts,
        _ADJOINTS[adjoint],
        checkpoints,
        progress,
        throw and traced,
    )
    if throw and not traced:
        _raise_if_failed(sol)
    return sol


@eqx.filter_jit
def _solve_jit(
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
    kind,
    checkpoints,
    progress,
    throw_inside,
):
    meter = progress_callback(t0, t1) if progress else None
    y0 = eqx.error_if(y0, ~jnp.all(jnp.isfinite(y0)), "`y0` contains NaN or inf.")
    y0 = eqx.error_if(y0, ~(t1 > t0), "`t1` must be greater than `t0`.")
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
    )
    if t_eval is not None:
        sol = eqx.tree_at(
            lambda s: (s.t_eval, s.y_eval),
            sol,
            (t_eval, interpolate(sol, t_eval)),
            is_leaf=lambda x: x is None,
        )
    if throw_inside:
        sol = sol.result.error_if(sol, sol.result != RESULTS.successful)
    return sol


def _raise_if_failed(sol: Solution):
    result = sol.result
    if np.ndim(result._value) != 0:
        failed = np.flatnonzero(np.asarray(result._value) != RESULTS.successful._value)
        if failed.size:
            raise SolveError(
                f"{failed.size} batch member(s) failed (indices {failed[:10].tolist()}"
                f"{'...' if failed.size > 10 else ''}); pass throw=False and inspect "
                "`Solution.result` per member."
            )
        return
    if result == RESULTS.successful:
        return
    k = int(sol.n_accepted)
    t = float(sol.t_final)
    h = float(sol.h_last)
    message = RESULTS[result]
    raise SolveError(
        f"nivpjax.solve failed at t = {t:.10g} after {k} accepted and "
        f"{int(sol.n_rejected)} rejected steps (last attempted step size {h:.3g}): {message}"
    )
