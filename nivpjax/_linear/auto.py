"""The default: a dense direct solve for small systems, matrix-free Krylov for large ones."""

import equinox as eqx

from .._custom_types import plain_int
from .base import AbstractLinearSolver
from .dense import DenseLU
from .krylov import Krylov


class AutoLinear(AbstractLinearSolver):
    r"""Chooses by the number of unknowns $n$ (known when the stage is traced, so the
    choice costs nothing at run time): [`nivpjax.DenseLU`][] up to `dense_max`
    unknowns, `krylov` above.

    The crossover is where a dense Newton iteration ($n$ residual products for the
    Jacobian plus an $O(n^3)$ LU) costs more than a Krylov solve (a few dozen products);
    measured on a spring-block chain (see `benchmarks/large_linalg.py`). Systems with
    dense coupling whose Krylov solves need many iterations (stiff stages of a dense
    elastic kernel) may prefer the dense path longer; pass
    `SemismoothNewton(linear_solver=...)` to choose.

    **Arguments:**

    - `dense_max`: the largest $n$ solved densely.
    - `krylov`: the [`nivpjax.Krylov`][] used above it.
    """

    dense_max: int = eqx.field(static=True, default=128, converter=plain_int)
    krylov: Krylov = eqx.field(default_factory=Krylov)

    def __check_init__(self):
        if not isinstance(self.dense_max, int) or isinstance(self.dense_max, bool):
            raise ValueError(f"`dense_max` must be an int, got {self.dense_max!r}.")

    def resolve(self, n):
        return DenseLU() if n <= self.dense_max else self.krylov

    def init(self, y):
        return self.resolve(y.shape[0]).init(y)

    def direction(self, G, y, g, scale, state, linearize=None):
        return self.resolve(y.shape[0]).direction(G, y, g, scale, state, linearize)

    def tangent_solve(self, g, b):
        return self.resolve(b.shape[0]).tangent_solve(g, b)
