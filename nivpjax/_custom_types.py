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
