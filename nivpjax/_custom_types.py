"""Type aliases used across nivpjax (documentation only; checked in tests when enabled)."""

from typing import Any, TypeAlias

from jaxtyping import Array, ArrayLike, Bool, Float, Int, PyTree


Y: TypeAlias = Float[Array, " n"]
Args: TypeAlias = PyTree[Any]
RealScalarLike: TypeAlias = float | int | Float[ArrayLike, ""]
FloatScalar: TypeAlias = Float[Array, ""]
IntScalar: TypeAlias = Int[Array, ""]
BoolScalar: TypeAlias = Bool[Array, ""]
