"""The embedded backward Euler / trapezoidal pair."""

import equinox as eqx

from .._nonlinear import AbstractNonlinearSolver
from .._solution import StepStats
from .base import AbstractStepper, StepOutput, default_solver, stats_of


class EmbeddedBETR(AbstractStepper):
    r"""Backward Euler and the trapezoidal rule from the same $y_0$; their difference
    $y_{TR} - y_{BE} = O(h^2)$ estimates the local error of backward Euler (`error_order`
    2). `propagate="backward_euler"` (default) advances the L-stable, damped solution, which
    is what nonsmooth problems want; `"trapezoidal"` advances the second-order one (local
    extrapolation). Two stage solves per step; the trapezoidal stage starts from the backward
    Euler result.
    """

    solver: AbstractNonlinearSolver = eqx.field(default_factory=default_solver)
    propagate: str = eqx.field(static=True, default="backward_euler")

    def __check_init__(self):
        if self.propagate not in ("backward_euler", "trapezoidal"):
            raise ValueError(
                f"`propagate` must be 'backward_euler' or 'trapezoidal', got {self.propagate!r}."
            )

    @property
    def order(self) -> int:
        return 1 if self.propagate == "backward_euler" else 2

    @property
    def error_order(self) -> int:
        return 2

    def step(self, model, t0, h, y0, args):
        t1 = t0 + h
        f0 = model.f(t0, y0, args)
        be, mult_be = model.solve_stage(self.solver, t1, h, y0, None, 1.0, y0, y0, args)
        tr, mult_tr = model.solve_stage(self.solver, t1, h, y0, f0, 0.5, y0, be.value, args)
        if self.propagate == "backward_euler":
            y1, multipliers = be.value, mult_be
        else:
            y1, multipliers = tr.value, mult_tr
        stats = StepStats.combine(stats_of(be), stats_of(tr))
        return StepOutput(y1=y1, y_error=tr.value - be.value, multipliers=multipliers, stats=stats)
