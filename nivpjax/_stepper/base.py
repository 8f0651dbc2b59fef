"""The stepper interface."""

import abc

import equinox as eqx
from jaxtyping import Array, Float

from .._model import Model
from .._nonlinear import AbstractNonlinearSolver, SemismoothNewton
from .._solution import StepStats


class StepOutput(eqx.Module):
    """One attempted step: the candidate `y1`, its local error estimate `y_error` (`None` when
    the scheme has none), the stage residual at `y1` (`multipliers`), and `stats`."""

    y1: Float[Array, " n"]
    y_error: Float[Array, " n"] | None
    multipliers: Float[Array, " n"]
    stats: StepStats


class AbstractStepper(eqx.Module):
    """An implicit one-step scheme whose stages are variational inequalities solved by
    `solver`.

    Subclasses implement `step(model, t0, h, y0, args) -> StepOutput` and declare `order`
    (of the propagated solution) and `error_order` (the power of $h$ in the local error
    estimate, used by controllers; 0 when there is no embedded estimate).
    """

    solver: eqx.AbstractVar[AbstractNonlinearSolver]

    @property
    @abc.abstractmethod
    def order(self) -> int: ...

    @property
    def error_order(self) -> int:
        return 0

    @abc.abstractmethod
    def step(self, model: Model, t0, h, y0, args) -> StepOutput: ...


def default_solver() -> AbstractNonlinearSolver:
    return SemismoothNewton()


def stats_of(sol) -> StepStats:
    return StepStats(
        iterations=sol.iterations, residual_norm=sol.residual_norm, nonlinear_result=sol.result
    )
