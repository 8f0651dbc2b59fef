"""The theta family: backward Euler, trapezoidal, and any theta in [1/2, 1]."""

import equinox as eqx

from .._nonlinear import AbstractNonlinearSolver
from .base import AbstractStepper, StepOutput, default_solver, stats_of


class _AbstractTheta(AbstractStepper):
    theta: eqx.AbstractVar[float]
    solver: eqx.AbstractVar[AbstractNonlinearSolver]

    @property
    def order(self) -> int:
        return 2 if self.theta == 0.5 else 1

    def step(self, model, t0, h, y0, args):
        t1 = t0 + h
        f0 = None if self.theta == 1.0 else model.f(t0, y0, args)
        sol, multipliers = model.solve_stage(self.solver, t1, h, y0, f0, self.theta, y0, y0, args)
        return StepOutput(y1=sol.value, y_error=None, multipliers=multipliers, stats=stats_of(sol))


class Theta(_AbstractTheta):
    r"""The theta method,
    $A(y_1 - y_0) = h[\theta f(t_1, y_1) + (1 - \theta) f(t_0, y_0)] + (\text{reaction})$,
    with algebraic rows collocated at $t_1$: $0 = f_{\text{alg}}(t_1, y_1)$ (averaging them
    would let multipliers oscillate from step to step).

    Order 2 for $\theta = 1/2$, 1 otherwise; A-stable for $\theta \ge 1/2$, L-stable only at
    $\theta = 1$. No embedded error estimate: adaptive runs use Richardson step doubling.
    """

    theta: float = 1.0
    solver: AbstractNonlinearSolver = eqx.field(default_factory=default_solver)

    def __check_init__(self):
        if not 0.5 <= self.theta <= 1.0:
            raise ValueError(f"`theta` must lie in [1/2, 1], got {self.theta}.")


class BackwardEuler(_AbstractTheta):
    """Backward (implicit) Euler: the theta method with $\\theta = 1$. Order 1, L-stable;
    with a projector, Moreau–Jean time stepping."""

    solver: AbstractNonlinearSolver = eqx.field(default_factory=default_solver)

    @property
    def theta(self) -> float:
        return 1.0


class Trapezoidal(_AbstractTheta):
    """The trapezoidal rule: the theta method with $\\theta = 1/2$. Order 2, A-stable, no
    damping (multipliers may ring after a switch: prefer Bathe for that)."""

    solver: AbstractNonlinearSolver = eqx.field(default_factory=default_solver)

    @property
    def theta(self) -> float:
        return 0.5
