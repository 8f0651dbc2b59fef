"""Type aliases used across nivpjax (documentation only; checked in tests when enabled)."""

from typing import Any, TypeAlias

from jaxtyping import Array, ArrayLike, Bool, Float, Int, PyTree


Y: TypeAlias = Float[Array, " n"]
Args: TypeAlias = PyTree[Any]
RealScalarLike: TypeAlias = float | int | Float[ArrayLike, ""]
FloatScalar: TypeAlias = Float[Array, ""]
IntScalar: TypeAlias = Int[Array, ""]
BoolScalar: TypeAlias = Bool[Array, ""]


def plain_int(value):
    """Converter for static integer fields: a NumPy integer becomes a Python int (equinox
    warns about array-like static fields); anything else is kept for the field's own check,
    so 2.0 or True are still rejected there, not silently truncated."""
    import numpy as np

    if isinstance(value, np.integer) and not isinstance(value, np.bool_):
        return int(value)
    return value


def runtime_float(value):
    """Converter for real scalars that must be run-time values of a compiled solve (a
    tolerance, a step bound): a Python or NumPy real scalar becomes a 0-d JAX array, weakly
    typed like the Python float it replaces (so it never promotes a float32 solve), and is
    then traced by `jit` instead of being baked into the program. `None`, arrays, tracers and
    anything invalid are kept as they are, for the field's own check.

    The array is made concrete even when the module is built inside a `jit` trace: a bare
    `jnp.asarray` there returns a tracer of that trace, and a module kept past it (the
    default controller cached by `solve`, a user's own) would carry a dead trace's tracer
    into later traces. JAX 0.10 takes a tracer of another trace silently as a constant of
    the program being traced (`DynamicJaxprTrace.to_jaxpr_tracer`); `jit` then moves such
    constants into arguments (`pjit._infer_params`, `separate_consts`) but its C++ fast
    path still calls the program without them: the second call of that `jit` fails with
    "Execution supplied 1 arguments but compiled program expected 6"."""
    import numpy as np

    if isinstance(value, (bool, np.bool_)):
        return value
    if isinstance(value, (float, int, np.floating, np.integer)):
        import jax
        import jax.numpy as jnp

        out = jnp.asarray(float(value))
        if isinstance(out, jax.core.Tracer):  # built inside a trace
            with jax.ensure_compile_time_eval():
                out = jnp.asarray(float(value))
        return out
    return value
