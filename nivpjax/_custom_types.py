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
    anything invalid are kept as they are, for the field's own check."""
    import numpy as np

    if isinstance(value, (bool, np.bool_)):
        return value
    if isinstance(value, (float, int, np.floating, np.integer)):
        import jax.numpy as jnp

        return jnp.asarray(float(value))
    return value
