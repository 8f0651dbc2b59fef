"""The composite Bathe scheme."""

import equinox as eqx
import jax.numpy as jnp

from .._nonlinear import AbstractNonlinearSolver
from .._solution import StepStats
from .base import AbstractStepper, StepOutput, default_solver, stats_of


class Bathe(AbstractStepper):
    r"""The composite scheme of Bathe & Noh (2012): a trapezoidal sub-step to
    $t_0 + \gamma h$, then a three-point backward difference through $t_0$, $t_0 + \gamma h$
    and $t_1$:

    $$ A(c_1 y_0 + c_2 y_\gamma + c_3 y_1) = f(t_1, y_1), \quad
       c_1 = \frac{1-\gamma}{\gamma h},\ c_2 = \frac{-1}{\gamma(1-\gamma) h},\
       c_3 = \frac{2-\gamma}{(1-\gamma) h}. $$

    Second order and L-stable: the backward-difference stage damps the ringing that the
    trapezoidal rule leaves after impacts and switches. Each stage is a VI with the model's
    projector. `gamma` defaults to 1/2. No embedded error estimate (adaptive runs use
    Richardson step doubling).

    If the first stage contains an impulse (an impact: see
    [`nivpjax.AbstractProjector.impulsive`][]) the backward difference would extrapolate
    across the velocity jump and inject energy; the second stage then restarts as a backward
    Euler step from $y_\gamma$ over $(1-\gamma)h$.
    """

    gamma: float = 0.5
    solver: AbstractNonlinearSolver = eqx.field(default_factory=default_solver)

    def __check_init__(self):
        if not 0.0 < self.gamma < 1.0:
            raise ValueError(f"`gamma` must lie in (0, 1), got {self.gamma}.")

    @property
    def order(self) -> int:
        return 2

    def step(self, model, t0, h, y0, args):
        g = self.gamma
        t_mid = t0 + g * h
        f0 = model.f(t0, y0, args)
        sol1, _ = model.solve_stage(self.solver, t_mid, g * h, y0, f0, 0.5, y0, y0, args)
        y_mid = sol1.value
        c1 = (1 - g) / g
        c2 = -1 / (g * (1 - g))
        c3 = (2 - g) / (1 - g)
        # c1 + c2 + c3 = 0: the stage is a backward Euler step of size h/c3 from an affine
        # combination of the two earlier points.
        y_base = -(c1 * y0 + c2 * y_mid) / c3
        h_eff = h / c3
        # After an impulse in the first stage the three points do not lie on one smooth
        # curve: restart the second stage as backward Euler from y_mid.
        jump = model.impulsive(t_mid, g * h, y0, y_mid, args)
        y_base = jnp.where(jump, y_mid, y_base)
        h_eff = jnp.where(jump, (1 - g) * h, h_eff)
        sol2, multipliers = model.solve_stage(
            self.solver, t0 + h, h_eff, y_base, None, 1.0, y_mid, y_mid, args
        )
        stats = StepStats.combine(stats_of(sol1), stats_of(sol2))
        return StepOutput(y1=sol2.value, y_error=None, multipliers=multipliers, stats=stats)
