"""The compile cache at the `solve` boundary.

`jax.jit` and `equinox.filter_jit` key a compiled program on the Python identity of every
function they are given. A model written as a closure (`def make(k): return lambda t, y,
args: -k * y`, or a script that rebuilds its callbacks on every call) is then a new program
each time, and every call pays for tracing and XLA compilation.

`CachedJit` keys the program on what was traced instead: the pytree structure, the static
configuration, and for each plain Python function its code object, its module and the
structure of its closure. Closed-over arrays and floats are hoisted into arguments of the
compiled program (a hand-written `jax.closure_convert` that works before tracing, so the
lookup costs no trace), so closures of the same code with constants that differ only in
value share one compilation. If a hoisted constant must be concrete (Python control flow on
a closed-over float, NumPy on a closed-over array), the trace raises a concretisation error;
that structure is then compiled with its closures as static values, keyed by identity, which
is exactly `jax.jit`'s behaviour.

The cache holds at most `maxsize` programs (least recently used evicted first). Each program
is a `jax.jit` function, which compiles once per shape, dtype and weak type of its array
arguments.
"""

import collections
import contextlib
import functools
import threading
import types
import weakref
from typing import Any

import equinox as eqx
import jax
import numpy as np

from ._compiler import call_top_level, compiler_options
from ._stored_loop import instantiate_zero, is_symbolic_zero


_HOIST_ERRORS = (
    jax.errors.ConcretizationTypeError,
    jax.errors.TracerArrayConversionError,
    jax.errors.TracerIntegerConversionError,
)


class _Identity:
    """A key for an unhashable object (or a module's globals): equal only to itself. Holds
    the object, so its `id` cannot be reused while the key lives."""

    __slots__ = ("obj",)

    def __init__(self, obj):
        self.obj = obj

    def __hash__(self):
        return id(self.obj)

    def __eq__(self, other):
        return isinstance(other, _Identity) and other.obj is self.obj


_DYN = object()  # placeholder of a dynamic leaf in a spec


def _is_array(x) -> bool:
    return isinstance(x, (jax.Array, np.ndarray, np.generic)) and not isinstance(x, np.bool_)


def _static(x):
    try:
        hash(x)
    except TypeError:
        return ("id", _Identity(x))
    return ("static", x)


class _Splitter:
    """Separates a pytree into a hashable spec (the traced structure) and a list of dynamic
    leaves. `hoist=False` reproduces `equinox.filter_jit`: arrays dynamic, the rest static."""

    def __init__(self, hoist: bool):
        self.hoist = hoist
        self.dynamic: list[Any] = []
        self._path: set[int] = set()

    def tree(self, tree, in_closure: bool = False):
        leaves, treedef = jax.tree_util.tree_flatten(tree)
        return treedef, tuple(self.leaf(x, in_closure) for x in leaves)

    def leaf(self, x, in_closure: bool):
        if _is_array(x) or (
            in_closure and isinstance(x, (float, complex)) and not isinstance(x, bool)
        ):
            self.dynamic.append(x)
            return _DYN
        if self.hoist and isinstance(x, types.FunctionType) and id(x) not in self._path:
            return self.function(x)
        return _static(x)

    @contextlib.contextmanager
    def _visiting(self, f):
        # Functions being keyed, so that recursion through closures and globals stops.
        self._path.add(id(f))
        try:
            yield
        finally:
            self._path.discard(id(f))

    def function(self, f: types.FunctionType):
        with self._visiting(f):
            cells = []
            for cell in f.__closure__ or ():
                try:
                    content = cell.cell_contents
                except ValueError:  # an empty cell (a name assigned later)
                    cells.append(None)
                    continue
                cells.append(self.tree(content, in_closure=True))
            defaults = None if f.__defaults__ is None else self.tree(f.__defaults__, True)
            kwdefaults = None if f.__kwdefaults__ is None else self.tree(f.__kwdefaults__, True)
            return (
                "fn",
                f.__code__,
                _Identity(f.__globals__),
                self.globals_key(f),
                f.__name__,
                tuple(cells),
                defaults,
                kwdefaults,
            )

    def globals_key(self, f: types.FunctionType):
        """The module-level names `f` reads, with their values: a program traced with one
        value of a global must not serve a call made after the global changed (`jax.jit`
        retraces a new function object; so must we). Floats and other hashables key by
        value, arrays and other unhashables by identity, functions by identity and,
        recursively, by the globals they read."""
        items = []
        for name in _global_names(f.__code__):
            if name not in f.__globals__:
                continue
            value = f.__globals__[name]
            if isinstance(value, types.ModuleType):
                items.append((name, ("module", value.__name__)))
            elif isinstance(value, types.FunctionType):
                inner = ()
                if id(value) not in self._path:
                    with self._visiting(value):
                        inner = self.globals_key(value)
                items.append((name, ("gfn", _Identity(value), inner)))
            else:
                items.append((name, _static(value)))
        return tuple(items)


@functools.lru_cache(maxsize=1024)
def _global_names(code: types.CodeType) -> tuple:
    # The names `code` and its nested code objects may read as globals, sorted; computed
    # once per code object (this runs on every cache lookup).
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            names.update(_global_names(const))
    return tuple(sorted(names))


def _rebuild_tree(spec, dynamic):
    treedef, leaves = spec
    return jax.tree_util.tree_unflatten(treedef, [_rebuild_leaf(s, dynamic) for s in leaves])


def _rebuild_leaf(spec, dynamic):
    if spec is _DYN:
        return next(dynamic)
    kind = spec[0]
    if kind == "static":
        return spec[1]
    if kind == "id":
        return spec[1].obj
    _, code, globals_, _, name, cells, defaults, kwdefaults = spec
    closure = tuple(
        types.CellType() if c is None else types.CellType(_rebuild_tree(c, dynamic)) for c in cells
    )
    defaults = None if defaults is None else _rebuild_tree(defaults, dynamic)
    f = types.FunctionType(code, globals_.obj, name, defaults, closure or None)
    if kwdefaults is not None:
        f.__kwdefaults__ = _rebuild_tree(kwdefaults, dynamic)
    return f


class CacheInfo(eqx.Module):
    """Counters of a [`CachedJit`][]: `traces` (programs traced, i.e. compilations),
    `hits` and `misses` of the structural lookup, `fallbacks` (structures whose closures had
    to stay static) and `size` (programs held)."""

    traces: int
    hits: int
    misses: int
    fallbacks: int
    size: int


class PreparedCall:
    """One call, split and looked up; `known` says whether this structure has already been
    traced with these argument types (so input checks that trace user code can be skipped)."""

    __slots__ = ("owner", "key", "dynamic", "signature", "args")

    def __init__(self, owner, key, dynamic, args):
        self.owner = owner
        self.key = key
        self.dynamic = dynamic
        self.args = args
        if any(isinstance(x, jax.core.Tracer) for x in dynamic):
            self.signature = None  # under an outer transformation: never "known"
        else:
            self.signature = (key, tuple(_aval_key(x) for x in dynamic))

    @property
    def known(self) -> bool:
        return self.signature is not None and self.signature in self.owner._seen

    def __call__(self):
        return self.owner._call(self)

    def with_vjp(self):
        """The call, reverse-mode differentiated through compiled programs of its own (see
        `CachedJit.call_with_vjp`); the same values."""
        return self.owner.call_with_vjp(self)


def _any_tracer(tree) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(tree))


def _aval_key(x):
    if isinstance(x, (float, complex)):
        return type(x)
    return (x.shape, x.dtype, getattr(x, "weak_type", False))


# Every `CachedJit`, for `clear_caches`.
_INSTANCES: "weakref.WeakSet[CachedJit]" = weakref.WeakSet()


def clear_caches():
    """Drop every compiled program nivpjax holds (the solve boundary's cache) and JAX's own
    caches (`jax.clear_caches()`), so that the compiled code can be freed; the next call of
    each program traces and compiles again (or loads it from the persistent cache, see
    [`nivpjax.enable_persistent_cache`][]).

    A process that compiles thousands of distinct programs (a long notebook, a sweep over
    model structures, a test suite) needs it: each XLA CPU executable holds about twenty
    memory mappings while it lives, and Linux allows a process 65 530 of them
    (`vm.max_map_count`). Past that, compilation fails, and jaxlib 0.10 then crashes the
    process (a segmentation fault or an abort while it raises the compile error) rather
    than raising.
    """
    for cached in list(_INSTANCES):
        cached.cache_clear()
    jax.clear_caches()


class CachedJit:
    """`jax.jit` of `fn(*args)` keyed by the traced structure of `args` (see the module
    docstring). Arrays anywhere in `args` and floats closed over by functions in `args` are
    run-time values; everything else is static configuration."""

    def __init__(self, fn, maxsize: int = 32):
        self.fn = fn
        self.maxsize = maxsize
        self._programs: collections.OrderedDict = collections.OrderedDict()
        self._static_only: set = set()
        self._seen: set = set()
        self._lock = threading.Lock()
        self._counts = collections.Counter()
        self._apply: dict = {}
        functools.update_wrapper(self, fn)
        _INSTANCES.add(self)

    def prepare(self, *args) -> PreparedCall:
        splitter = _Splitter(hoist=True)
        spec = splitter.tree(args)
        key = ("hoisted", spec)
        if key in self._static_only:
            splitter = _Splitter(hoist=False)
            key = ("static", splitter.tree(args))
        return PreparedCall(self, key, splitter.dynamic, args)

    def __call__(self, *args):
        return self.prepare(*args)()

    def _program(self, key, nested: bool = False):
        """The jitted program of the structure `key`. A top-level call compiles with
        nivpjax's `compiler_options()`; a call under an outer `jit` or other
        transformation (`nested`) goes through a plain `jax.jit` of the same function,
        since JAX takes compiler options on top-level jits only (the outer program's own
        options then apply)."""
        with self._lock:
            programs = self._programs.get(key)
            if programs is not None:
                self._programs.move_to_end(key)
                self._counts["hits"] += 1
                return programs[nested]
            self._counts["misses"] += 1
            spec = key[1]

            def program_fn(dynamic):
                self._counts["traces"] += 1
                return self.fn(*_rebuild_tree(spec, iter(dynamic)))

            program_fn.__name__ = getattr(self.fn, "__name__", "program")
            programs = (
                jax.jit(program_fn, compiler_options=compiler_options()),
                jax.jit(program_fn),
            )
            self._programs[key] = programs
            while len(self._programs) > self.maxsize:
                old, _ = self._programs.popitem(last=False)
                self._seen = {s for s in self._seen if s[0] != old}
            return programs[nested]

    def _call(self, call: PreparedCall):
        try:
            out = self._run(call)
        except _HOIST_ERRORS:
            if call.key[0] != "hoisted":
                raise
            return self._static_after_failure(call)()
        if call.signature is not None:
            self._seen.add(call.signature)
        return out

    def _run(self, call: PreparedCall):
        nested = call.signature is None  # a tracer among the arguments
        return call_top_level(lambda n: self._program(call.key, n), nested, call.dynamic)

    def call_with_vjp(self, call: PreparedCall):
        """`call()` with a `jax.custom_vjp` at this boundary: under reverse mode the
        forward pass runs a cached program that returns the values and the VJP's
        residuals (`jax.vjp` of the function, differentiated in the perturbed arguments
        only), and the backward pass a cached program that applies it. A top-level
        `jax.grad` then calls both as top-level programs, compiled once per structure
        with `compiler_options()`, rather than having JAX split and compile the
        differentiated program itself without them. A call with no tracer among its
        arguments cannot be differentiated and is the plain call."""
        if call.signature is not None:
            return self._call(call)
        try:
            return self._run_vjp(call)
        except _HOIST_ERRORS:
            if call.key[0] != "hoisted":
                raise
            return self._static_after_failure(call).with_vjp()

    def _static_after_failure(self, call: PreparedCall) -> PreparedCall:
        # A hoisted program that failed to trace: forget it, remember its key as static
        # only, and prepare the call with its closed-over values as constants.
        with self._lock:
            self._programs.pop(call.key, None)
            self._static_only.add(call.key)
            self._counts["fallbacks"] += 1
        return self.prepare_static(call)

    def _run_vjp(self, call: PreparedCall):
        key = call.key
        box = {}  # the perturbed arguments, from the forward pass to the backward pass

        @jax.custom_vjp
        def run(*dynamic):
            return self._run(PreparedCall(self, key, list(dynamic), call.args))

        def run_fwd(*primals):
            dynamic = [p.value for p in primals]
            box["perturbed"] = perturbed = tuple(bool(p.perturbed) for p in primals)
            nested = _any_tracer(dynamic)
            program = lambda n: self._vjp_program(key, perturbed, n)  # noqa: E731
            return call_top_level(program, nested, dynamic)

        def run_bwd(vjp_fn, cotangent):
            cotangent = jax.tree.map(instantiate_zero, cotangent, is_leaf=is_symbolic_zero)
            nested = _any_tracer((vjp_fn, cotangent))
            grads = iter(call_top_level(self._apply_vjp, nested, vjp_fn, cotangent))
            return tuple(next(grads) if p else None for p in box["perturbed"])

        run.defvjp(run_fwd, run_bwd, symbolic_zeros=True)
        return run(*call.dynamic)

    def _vjp_program(self, key, perturbed: tuple, nested: bool):
        # The forward program of reverse mode: values and `jax.vjp`'s residuals, as a
        # `jax.vjp` function (a pytree of arrays), differentiated in the perturbed
        # arguments only.
        vjp_key = ("vjp", key, perturbed)
        with self._lock:
            programs = self._programs.get(vjp_key)
            if programs is None:
                spec = key[1]

                def vjp_fn(dynamic):
                    self._counts["traces"] += 1

                    def fn(diff):
                        it = iter(diff)
                        full = [next(it) if p else x for x, p in zip(dynamic, perturbed)]
                        return self.fn(*_rebuild_tree(spec, iter(full)))

                    return jax.vjp(fn, [x for x, p in zip(dynamic, perturbed) if p])

                vjp_fn.__name__ = getattr(self.fn, "__name__", "program") + "_vjp"
                programs = (
                    jax.jit(vjp_fn, compiler_options=compiler_options()),
                    jax.jit(vjp_fn),
                )
                self._programs[vjp_key] = programs
                while len(self._programs) > self.maxsize:
                    self._programs.popitem(last=False)
            else:
                self._programs.move_to_end(vjp_key)
            return programs[nested]

    def _apply_vjp(self, nested: bool):
        # The backward program: a `jax.vjp` function applied to a cotangent (one jit;
        # it compiles once per VJP structure, i.e. per forward program).
        if nested not in self._apply:
            options = {} if nested else compiler_options()
            self._apply[nested] = jax.jit(lambda f, ct: f(ct)[0], compiler_options=options)
        return self._apply[nested]

    def prepare_static(self, call: PreparedCall) -> PreparedCall:
        args = _rebuild_tree(call.key[1], iter(call.dynamic))
        splitter = _Splitter(hoist=False)
        return PreparedCall(self, ("static", splitter.tree(args)), splitter.dynamic, args)

    def cache_info(self) -> CacheInfo:
        return CacheInfo(
            traces=self._counts["traces"],
            hits=self._counts["hits"],
            misses=self._counts["misses"],
            fallbacks=self._counts["fallbacks"],
            size=len(self._programs),
        )

    def cache_clear(self):
        with self._lock:
            self._programs.clear()
            self._static_only.clear()
            self._seen.clear()
            self._apply.clear()


def enable_persistent_cache(path: str, min_compile_time_secs: float = 0.0):
    """Opt in to JAX's persistent compilation cache in the directory `path`: compiled XLA
    programs are written there and a later process (the second run of a script) loads them
    instead of compiling. Tracing still happens in every process; only XLA compilation is
    skipped. Call it once, before the first solve.

    **Arguments:**

    - `path`: a writable directory (created if missing).
    - `min_compile_time_secs`: only programs that took at least this long to compile are
      stored (JAX's default is 1 s; 0 stores all).
    """
    import os

    path = os.path.abspath(os.path.expanduser(os.fspath(path)))
    os.makedirs(path, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time_secs))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
