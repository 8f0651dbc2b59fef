"""Models written with NumPy: run on the host through `jax.pure_callback`, differentiated by
central finite differences.

A reference user's `fun(t, y)` returns `np.array([y[1], -9.81])`; JAX cannot trace it. The
drop-in detects that before any work (a trace that raises a concretisation error), checks
the function once on NumPy input, and wraps it in a `HostFunction`: a `jax.custom_jvp` whose
primal is a `pure_callback` and whose JVP is $J(x)\\,\\dot x$ with $J$ built on the host by
central differences. The JVP is linear in the tangent, so forward and reverse mode work; $J$
is itself a `HostFunction`, so second derivatives (finite differences of finite differences)
work too, less accurately. Under `vmap` the callback receives the batch (`expand_dims`) and
loops over it on the host: one round trip per batched call, not one per member.
"""

import collections
import warnings

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.custom_derivatives import SymbolicZero


class NumpyModelWarning(UserWarning):
    """A callable given to the drop-in is written with NumPy and runs on the host (slow).
    Filter it with `warnings.filterwarnings("ignore", category=NumpyModelWarning)`."""


class ModelError(ValueError):
    """A callable given to the drop-in cannot run: neither JAX can trace it nor can it run
    on the host. The message says what to change."""


# Central differences: the step that balances truncation (h^2) against round-off (eps / h).
_STEP = float(np.finfo(np.float64).eps ** (1 / 3))


def _fd_step(x: float) -> float:
    return _STEP * max(1.0, abs(x))


def _encode(x: np.ndarray) -> np.ndarray:
    x = np.ascontiguousarray(x, np.float64)
    return x.view(np.uint32).reshape(x.shape + (2,))


def _decode(words) -> np.ndarray:
    words = np.ascontiguousarray(words, np.uint32)
    return words.view(np.float64).reshape(words.shape[:-1])


def _call_host(fn, args, out_shape):
    out = np.asarray(fn(*args), dtype=np.float64)
    return out.reshape(out_shape)


class HostFunction:
    """`fn(*arrays) -> array of shape out_shape`, evaluated in float64 on the host; JAX sees
    a differentiable, batchable function of the same arguments. `core_shapes[i]` is the
    shape of argument `i` (leading axes beyond it are a `vmap` batch)."""

    def __init__(self, fn, out_shape, core_shapes, name):
        self.fn = fn
        self.out_shape = tuple(out_shape)
        self.core_shapes = tuple(tuple(s) for s in core_shapes)
        self.core_ndims = tuple(len(s) for s in self.core_shapes)
        self.name = name
        self._jacobians = {}
        self._call = jax.custom_jvp(self._primal)
        self._call.defjvp(self._jvp, symbolic_zeros=True)

    def __call__(self, *args):
        dtype = jnp.result_type(float)
        return self._call(*(jnp.asarray(a, dtype) for a in args))

    # -- the host side -------------------------------------------------------------------
    def _batched(self, host_fn, out_shape, *arrays):
        """Evaluate `host_fn` on each member of the batch `arrays` carry (leading axes)."""
        arrays = [np.asarray(a, np.float64) for a in arrays]
        batch = np.broadcast_shapes(
            *(a.shape[: a.ndim - k] for a, k in zip(arrays, self.core_ndims))
        )
        out = np.empty(batch + out_shape, np.float64)
        for index in np.ndindex(*batch):
            member = []
            for a, k in zip(arrays, self.core_ndims):
                lead = a.shape[: a.ndim - k]
                at = index[len(batch) - len(lead) :]
                sub = tuple(i if n > 1 else 0 for i, n in zip(at, lead))
                member.append(np.array(a[sub], np.float64))  # a writable copy
            out[index] = host_fn(*member)
        return out

    def _value(self, *member):
        return _call_host(self.fn, member, self.out_shape)

    def _jacobian_value(self, wrt, *member):
        """Central differences of `fn` with respect to the arguments `wrt`, concatenated along
        the last axis: shape `out_shape + (total size,)`."""
        columns = []
        for i in wrt:
            x = member[i]
            flat = x.ravel()
            for k in range(flat.size):
                h = _fd_step(float(flat[k]))
                plus, minus = flat.copy(), flat.copy()
                plus[k] += h
                minus[k] -= h
                width = plus[k] - minus[k]  # the step actually taken, after rounding
                args_p = member[:i] + (plus.reshape(x.shape),) + member[i + 1 :]
                args_m = member[:i] + (minus.reshape(x.shape),) + member[i + 1 :]
                f_p = _call_host(self.fn, args_p, self.out_shape)
                f_m = _call_host(self.fn, args_m, self.out_shape)
                columns.append((f_p - f_m) / width)
        return np.stack(columns, axis=-1)

    # -- the JAX side --------------------------------------------------------------------
    def _primal(self, *args):
        dtype = jnp.result_type(*args)
        if jnp.dtype(dtype).itemsize == 4:
            return jax.pure_callback(
                lambda *a: self._batched(self._value, self.out_shape, *a).astype(dtype),
                jax.ShapeDtypeStruct(self.out_shape, dtype),
                *args,
                vmap_method="expand_dims",
            )
        # float64 travels as pairs of uint32: the callback's thread converts its inputs and
        # outputs under its own x64 mode, which a caller's scoped `jax.enable_x64` does not
        # reach, and would narrow float64 to float32 there.
        words = jax.pure_callback(
            lambda *a: _encode(self._batched(self._value, self.out_shape, *map(_decode, a))),
            jax.ShapeDtypeStruct(self.out_shape + (2,), jnp.uint32),
            *(lax.bitcast_convert_type(a, jnp.uint32) for a in args),
            vmap_method="expand_dims",
        )
        return lax.bitcast_convert_type(words, dtype)

    def jacobian(self, wrt):
        """The finite-difference Jacobian with respect to the arguments `wrt` (a tuple of
        indices), as a `HostFunction` of the same arguments (so it is differentiable too)."""
        if wrt not in self._jacobians:
            size = sum(int(np.prod(self.core_shapes[i])) for i in wrt)

            def fd(*member, wrt=wrt):
                return self._jacobian_value(wrt, *member)

            self._jacobians[wrt] = HostFunction(
                fd, self.out_shape + (size,), self.core_shapes, f"the Jacobian of {self.name}"
            )
        return self._jacobians[wrt]

    def _jvp(self, primals, tangents):
        out = self._call(*primals)
        wrt = tuple(i for i, d in enumerate(tangents) if not isinstance(d, SymbolicZero))
        if not wrt:
            return out, jnp.zeros_like(out)
        J = self.jacobian(wrt)(*primals)
        tangent = jnp.zeros_like(out)
        start = 0
        for i in wrt:
            shape = self.core_shapes[i]
            size = int(np.prod(shape))
            block = J[..., start : start + size].reshape(self.out_shape + shape)
            d = jnp.asarray(tangents[i], out.dtype)
            tangent = tangent + jnp.tensordot(block, d, axes=len(shape))
            start += size
        return out, tangent


def describe(fn) -> str:
    code = getattr(fn, "__code__", None)
    name = getattr(fn, "__qualname__", type(fn).__name__)
    if code is None:
        return name
    return f"{name} ({code.co_filename}:{code.co_firstlineno})"


def _model_key(fn):
    # One model = one piece of code: a lambda rebuilt on every call is the same model.
    return getattr(fn, "__code__", None) or id(fn)


_WARNED: set = set()
_WRAPPERS: collections.OrderedDict = collections.OrderedDict()


def warn_once(hosted: dict):
    """One `NumpyModelWarning` per model (the set of hosted callables' code)."""
    if not hosted:
        return
    key = tuple(sorted((role, str(_model_key(fn))) for role, fn in hosted.items()))
    if key in _WARNED:
        return
    _WARNED.add(key)
    names = ", ".join(f"`{role}` = {describe(fn)}" for role, fn in hosted.items())
    warnings.warn(
        f"solve_ivp_ns: {names} use(s) NumPy, which JAX cannot trace, so each call runs on "
        "the host through jax.pure_callback and its derivatives are central finite "
        "differences (2 calls per component of the state). This is slow: every evaluation "
        "leaves the compiled program. To run at full speed, write the model with "
        "jax.numpy: `import jax.numpy as jnp`, use `jnp.` where you used `np.`, "
        "`y.at[i].set(v)` instead of assigning into an array, and `jnp.where(c, a, b)` "
        "instead of `if` on values of `y`. Silence this with warnings.filterwarnings("
        "'ignore', category=nivpjax.compat.NumpyModelWarning).",
        NumpyModelWarning,
        stacklevel=3,
    )


def _probe(fn, role, signature, example, source, traced):
    """Call `fn` once on float64 NumPy copies of `example`: it must not fail, must not
    modify its arguments, and must return real numbers. Returns the output's shape."""
    before = [np.array(a, np.float64) for a in example]
    given = [np.array(a, np.float64) for a in example]
    try:
        out = fn(*given)
    except Exception as err:
        raise ModelError(
            f"solve_ivp_ns: `{role}` ({describe(source)}) can neither be traced by JAX nor run "
            f"on NumPy input: called as {signature} with NumPy arrays it raised "
            f"{type(err).__name__}: {err}. It must accept {signature} with float arrays and "
            "return an array of floats (traced by JAX it raised "
            f"{type(traced).__name__}: {str(traced).splitlines()[0]})."
        ) from err
    for name, a, b in zip(signature.strip("()").split(", "), before, given):
        if not np.array_equal(a, b, equal_nan=True):
            raise ModelError(
                f"solve_ivp_ns: `{role}` ({describe(source)}) modifies its argument `{name}` in "
                "place. The solver evaluates it at trial points and reuses them, so it must "
                "not write into its inputs: build and return a new array (`out = "
                f"np.empty_like({name}); out[0] = ...`, or better with jax.numpy, "
                f"`{name}.at[i].set(v)`)."
            )
    try:
        value = np.asarray(out, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ModelError(
            f"solve_ivp_ns: `{role}` ({describe(source)}) must return an array of real numbers, "
            f"got {type(out).__name__}: {err}."
        ) from None
    if not np.all(np.isfinite(value)):
        raise ModelError(
            f"solve_ivp_ns: `{role}` ({describe(source)}) returned non-finite values at the "
            f"initial point: {value}."
        )
    return value.shape


def _trace_error(fn, example):
    """None when JAX traces `fn`; else the error: a concretisation error means NumPy (or
    Python control flow on values), anything else may be a call JAX cannot trace (SciPy,
    an in-place assignment): the host probe decides."""
    try:
        jax.eval_shape(fn, *example)
    except Exception as err:  # noqa: BLE001 - reported with the host probe's own error
        return err
    return None


def adapt(fn, role, signature, example, expected_shape=None, hosted=None, source=None):
    """`fn` itself when JAX can trace it; otherwise a `HostFunction` of the same arguments
    (the user's callable `source`, default `fn`, is recorded in `hosted[role]`).
    `expected_shape`, if given, is checked on the host."""
    source = fn if source is None else source
    example = tuple(jnp.asarray(a, jnp.result_type(float)) for a in example)
    traced = _trace_error(fn, example)
    if traced is None:
        return fn
    shape = _probe(fn, role, signature, example, source, traced)
    if expected_shape is not None and shape != tuple(expected_shape):
        raise ModelError(
            f"solve_ivp_ns: `{role}` ({describe(source)}) returned shape {shape}; expected "
            f"{tuple(expected_shape)}."
        )
    if hosted is not None:
        hosted[role] = source
    core = tuple(np.shape(a) for a in example)
    # One compiled program per model: a lambda rebuilt on every call (same code, other
    # closure) reuses the wrapper, which calls the function it was last given. Calls are
    # synchronous (the drop-in reads its results before returning), so the program never
    # runs with a stale function.
    key = (_model_key(source), role, shape, core)
    wrapper = _WRAPPERS.get(key)
    if wrapper is None:
        wrapper = _WRAPPERS[key] = HostFunction(fn, shape, core, f"`{role}`")
        if len(_WRAPPERS) > 64:
            _WRAPPERS.popitem(last=False)
    wrapper.fn = fn
    wrapper.source = source  # holds it: a key made of its id stays unique
    _WRAPPERS.move_to_end(key)
    return wrapper
