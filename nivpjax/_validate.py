"""Input checks of [`nivpjax.solve`][]: every bad argument raises a `ValueError` or
`TypeError` naming it, before any work. Checks on traced values are left to the compiled
program (`equinox.error_if`)."""

import collections
import math

import jax
import jax.numpy as jnp
import numpy as np

from ._controller import AbstractController, PIDController
from ._projector import AbstractProjector, Identity
from ._stepper import AbstractStepper, Bathe, Richardson


ADJOINTS = {"checkpointed": "checkpointed", "forward": "lax"}


def is_traced(x) -> bool:
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x))


def is_batched(x) -> bool:
    """Whether a leaf of `x` is batched by a `jax.vmap` around this call, seen through the
    tracers of transformations inside it (a `grad`, a `jit`). A `jit` between the `vmap`
    and the call hides it: its function is traced unbatched."""
    for leaf in jax.tree.leaves(x):
        while isinstance(leaf, jax.core.Tracer):
            if type(leaf).__name__ == "BatchTracer":
                return True
            leaf = getattr(leaf, "val", getattr(leaf, "primal", None))
    return False


def concrete_float(name, value):
    if is_traced(value):
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


def check_y0(y0):
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
    if not is_traced(y0) and not np.all(np.isfinite(np.asarray(y0))):
        bad = np.flatnonzero(~np.isfinite(np.asarray(y0))).tolist()
        raise ValueError(f"`y0` contains NaN or inf at components {bad}.")
    return jnp.asarray(y0)


def check_mass_matrix(mass_matrix, n, dtype):
    if mass_matrix is None:
        return None, np.zeros(n, bool)
    if is_traced(mass_matrix):
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
    return A.astype(dtype), algebraic


def check_vector_field(vector_field, t0, y0, args):
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


_DEFAULTS = {}


def _default(name, cls):
    # Modules are immutable: one default instance serves every call (building one costs
    # tens of microseconds, a noticeable part of a cached call). The first solve may run
    # inside a user's `jit` and the instance outlives that trace, so a default must hold no
    # tracer: `runtime_float` makes its scalar fields concrete even there.
    if name not in _DEFAULTS:
        _DEFAULTS[name] = cls()
    return _DEFAULTS[name]


_MEMO: collections.OrderedDict = collections.OrderedDict()


def _memo(tag, module, compute):
    """`compute()` once per (tag, module object): modules are immutable, so a check that
    passed (or a wrapper built) for this very object holds for it again. Keyed by identity,
    holding the module so that its id is not reused; at most 64 entries."""
    key = (tag, id(module))
    hit = _MEMO.get(key)
    if hit is not None and hit[0] is module:
        _MEMO.move_to_end(key)
        return hit[1]
    out = compute()
    _MEMO[key] = (module, out)
    while len(_MEMO) > 64:
        _MEMO.popitem(last=False)
    return out


def as_array(x, dtype):
    """`x` as an array of `dtype`: NumPy where concrete, JAX where traced."""
    return jnp.asarray(x, dtype) if is_traced(x) else np.asarray(x, dtype)


def check_times(t0, t1):
    """Concrete `t0`, `t1` (or `None` where traced), with `t1 > t0` checked."""
    t0_c = concrete_float("t0", t0)
    t1_c = concrete_float("t1", t1)
    if t0_c is not None and t1_c is not None and not t1_c > t0_c:
        raise ValueError(f"`t1` must be greater than `t0`, got t0={t0_c}, t1={t1_c}.")
    return t0_c, t1_c


def check_max_steps(max_steps) -> int:
    if (
        not isinstance(max_steps, (int, np.integer))
        or isinstance(max_steps, (bool, np.bool_))
        or max_steps < 1
    ):
        raise ValueError(f"`max_steps` must be a positive int, got {max_steps!r}.")
    return int(max_steps)


def check_components(projector, stepper, controller, n):
    """The projector, stepper and controller, defaults filled in."""
    if projector is None:
        projector = _default("projector", Identity)
    if not isinstance(projector, AbstractProjector):
        raise TypeError(f"`projector` must be an AbstractProjector, got {projector!r}.")
    _memo(("validate", n), projector, lambda: projector.validate(n))
    if stepper is None:
        stepper = _default("stepper", Bathe)
    if not isinstance(stepper, AbstractStepper):
        raise TypeError(
            f"`stepper` must be an AbstractStepper (e.g. nivpjax.BackwardEuler()), got {stepper!r}."
        )
    if controller is None:
        controller = _default("controller", PIDController)
    if not isinstance(controller, AbstractController):
        raise TypeError(f"`controller` must be an AbstractController, got {controller!r}.")
    return projector, stepper, controller


def equinox_checkpoints(max_steps: int) -> int:
    """The checkpoint count equinox's checkpointed loop chooses for `max_steps` by default
    (its online Stumm-Walther schedule, of order sqrt(max_steps): 90 for 4096)."""
    return min(max(math.floor(-1.5 + math.sqrt(2 * max_steps + 0.25)) + 1, 1), max_steps)


def check_modes(error_estimate, adjoint, checkpoints, max_steps):
    """`error_estimate`, `adjoint` and `checkpoints`; returns the checkpoint count."""
    if error_estimate not in ("auto", "embedded", "richardson"):
        raise ValueError(
            "`error_estimate` must be one of 'auto', 'embedded', 'richardson', got "
            f"{error_estimate!r}."
        )
    if adjoint not in ADJOINTS:
        raise ValueError(f"`adjoint` must be 'checkpointed' or 'forward', got {adjoint!r}.")
    if checkpoints is None:
        return None
    if not isinstance(checkpoints, (int, np.integer)) or isinstance(checkpoints, (bool, np.bool_)):
        raise TypeError(f"`checkpoints` must be a positive int or None, got {checkpoints!r}.")
    if checkpoints < 1:
        raise ValueError(f"`checkpoints` must be a positive int or None, got {checkpoints!r}.")
    if adjoint != "checkpointed":
        raise ValueError(
            f"`checkpoints` only applies to adjoint='checkpointed', got adjoint={adjoint!r}."
        )
    return min(int(checkpoints), max_steps)


def check_tau(tau, n):
    """`tau` as a NumPy float array of shape `()` or `(n,)`."""
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
    return tau_arr


def check_equation_rows(equation_rows, n):
    if equation_rows is None:
        return None
    equation_rows = np.asarray(equation_rows, bool)
    if equation_rows.shape != (n,):
        raise ValueError(
            f"`equation_rows` must be a boolean array of shape ({n},), got {equation_rows.shape}."
        )
    return equation_rows


def _concrete_bound(value):
    return None if value is None or is_traced(value) else float(value)


def check_step_bounds(controller, h0):
    """`h0` and the controller's `h_min`/`h_max` (where concrete)."""
    if h0 is not None:
        h0_c = concrete_float("h0", h0)
        if h0_c is not None and not h0_c > 0:
            raise ValueError(f"`h0` must be positive, got {h0_c}.")
    h_min, h_max = (_concrete_bound(b) for b in controller.bounds)
    if h_min is not None and not (math.isfinite(h_min) and h_min >= 0):
        raise ValueError(f"`h_min` must be finite and non-negative, got {h_min}.")
    if h_max is not None and not (math.isfinite(h_max) and h_max > 0):
        raise ValueError(f"`h_max` must be finite and positive, got {h_max}.")
    if h0 is None and controller.requires_h0:
        raise ValueError(f"{type(controller).__name__} needs an initial step `h0`.")
    if h_min is not None and h_max is not None and h_min > h_max:
        raise ValueError(f"`h_min` must not exceed `h_max`, got {h_min} > {h_max}.")


def error_stepper(stepper, controller, error_estimate):
    """The stepper wrapped in Richardson step doubling where the controller needs an error
    estimate the stepper does not embed."""
    if controller.needs_error_estimate:
        if error_estimate == "embedded" and controller.step_doubling:
            raise ValueError(
                f"{type(controller).__name__} estimates by step doubling; "
                "error_estimate='embedded' cannot be used with it."
            )
        if error_estimate == "embedded" and stepper.error_order == 0:
            raise ValueError(
                f"{type(stepper).__name__} has no embedded error estimate; use "
                "error_estimate='richardson' or 'auto', or nivpjax.EmbeddedBETR."
            )
        doubling = error_estimate == "richardson" or controller.step_doubling
        if doubling or stepper.error_order == 0:
            stepper = _memo("richardson", stepper, lambda: Richardson(stepper))
    return stepper


def check_error_mask(controller, algebraic, n):
    error_mask = getattr(controller, "error_mask", None)
    if error_mask is None:
        return ~algebraic
    error_mask = np.asarray(error_mask, bool)
    if error_mask.shape != (n,):
        raise ValueError(
            f"`error_mask` must be a boolean array of shape ({n},), got {error_mask.shape}."
        )
    return error_mask


def check_t_eval(t_eval, dtype, t0_c, t1_c):
    if t_eval is None:
        return None
    if not is_traced(t_eval) and (
        isinstance(t_eval, (str, bytes))
        or not np.issubdtype(np.asarray(t_eval).dtype, np.number)
        or np.iscomplexobj(t_eval)
    ):
        raise TypeError(f"`t_eval` must be an array of real times, got {t_eval!r}.")
    xp = jnp if is_traced(t_eval) else np
    t_eval = xp.atleast_1d(xp.asarray(t_eval, dtype))
    if t_eval.ndim != 1:
        raise ValueError(f"`t_eval` must be 1-D, got shape {t_eval.shape}.")
    if not is_traced(t_eval) and t0_c is not None and t1_c is not None:
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
    return t_eval
