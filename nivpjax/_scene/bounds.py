"""Checks of an effect's bounds, before any work (traced bounds are the caller's)."""

import jax
import numpy as np


def check_bounds(lower, upper, n: int) -> None:
    """`lower` and `upper`: real, finite, broadcastable to `(n,)`, and `lower < upper`
    componentwise. Raises `TypeError` / `ValueError` naming the argument."""
    values = {}
    for name, value in (("lower", lower), ("upper", upper)):
        if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(value)):
            return  # batched or differentiated bounds: the caller's to check
        if callable(value) or isinstance(value, (str, bytes, bool)):
            raise TypeError(f"`{name}` must be a number or an array, got {value!r}.")
        array = np.asarray(value)
        if not np.issubdtype(array.dtype, np.number) or np.iscomplexobj(array):
            raise TypeError(f"`{name}` must be real, got {value!r}.")
        if array.ndim > 1 or array.size not in (1, n):
            raise ValueError(
                f"`{name}` must be a scalar or have shape ({n},) (one bound per "
                f"component), got shape {array.shape}."
            )
        if not np.all(np.isfinite(array)):
            raise ValueError(f"`{name}` must be finite, got {value!r}.")
        values[name] = np.broadcast_to(array, (n,))
    bad = np.flatnonzero(values["lower"] >= values["upper"])
    if bad.size:
        raise ValueError(
            f"`lower` must be below `upper`, got lower={lower!r}, upper={upper!r} "
            f"(components {bad.tolist()})."
        )
