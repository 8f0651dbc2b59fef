"""XLA compiler options for nivpjax's own compiled programs.

A solve is a while loop over a few hundred tiny kernels (states of a handful of entries).
On CPU, XLA's newer fusion emitters spend most of the compile time on them for no run-time
gain at that size: with the legacy emitters the default bouncing-ball solve compiled in
0.96 s of XLA time instead of 2.13 s (the relay 0.77 s instead of 1.50 s), and ran as fast
(155 and 161 µs a call; `benchmarks/results/speed.md`). The options apply to the programs
nivpjax compiles (`solve`, `Scene.solve`, `solve_batched`, the compat entry point, the
training and environment programs of `nivpjax.learn` and `nivpjax.rl`), never to the
user's others; pass `compiler_options()` to `jax.jit` to give a jitted function of your
own that wraps a solve the same compile time.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp


_CPU = {"xla_cpu_use_fusion_emitters": False}


@functools.cache
def _accepted(name: str, value) -> bool:
    # An option this XLA does not know is an error at compile time: probe once per process
    # (a one-op program, a few milliseconds) so that a newer XLA without it still works.
    try:
        jax.jit(jnp.negative, compiler_options={name: value}).lower(1.0).compile()
    except Exception:  # noqa: BLE001 (XLA raises its own runtime error type)
        return False
    return True


def compiler_options(backend: str | None = None) -> dict:
    """The XLA compiler options nivpjax compiles its programs with on `backend` (the
    default backend if `None`): on CPU, the legacy fusion emitters
    (`xla_cpu_use_fusion_emitters=False`), which compile nivpjax's small-state loops in
    about half the time at the same run time; on other backends none. An option the
    installed XLA does not accept is left out.

    Use it for a `jax.jit` of your own around solves (a `vmap` over a sweep, a loss):
    `jax.jit(f, compiler_options=nj.compiler_options())`. Without it such a program
    compiles with XLA's defaults, correctly but more slowly."""
    backend = jax.default_backend() if backend is None else backend
    if backend != "cpu":
        return {}
    return {name: value for name, value in _CPU.items() if _accepted(name, value)}


def call_top_level(program, nested: bool, *args, **kwargs):
    """`program(nested)(*args, **kwargs)`, where `program(False)` is compiled with
    `compiler_options()` and `program(True)` without them. A call that looked top-level
    (`nested=False`) but runs under an outer `jit` whose arguments reach it as constants
    only is refused by JAX at trace time; it then goes through `program(True)`."""
    try:
        return program(nested)(*args, **kwargs)
    except ValueError as error:
        if nested or "top-level" not in str(error):
            raise
        return program(True)(*args, **kwargs)


def filter_jit(fn):
    """`equinox.filter_jit` of `fn`, with `compiler_options()` when called at top level
    (built on the first call, so that importing nivpjax initialises no backend); a plain
    `equinox.filter_jit` under an outer transformation, where JAX takes no compiler
    options."""
    jitted = {}

    def program(nested):
        if nested not in jitted:
            jitted[nested] = eqx.filter_jit(
                fn, compiler_options={} if nested else compiler_options()
            )
        return jitted[nested]

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        nested = any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves((args, kwargs)))
        return call_top_level(program, nested, *args, **kwargs)

    return wrapper
