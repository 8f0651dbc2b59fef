"""Richardson step doubling: an error estimate for any stepper."""

import jax
import jax.numpy as jnp

from .._solution import StepStats
from .base import AbstractStepper, StepOutput


class Richardson(AbstractStepper):
    r"""Wrap a stepper of order $p$: take one step of size $h$ and two of size $h/2$, and
    estimate the error of the two half steps as $(y_{h/2,h/2} - y_h)/(2^p - 1)$
    (`error_order` $p + 1$). The two half steps are propagated. Costs three steps per step.
    """

    stepper: AbstractStepper

    @property
    def solver(self):
        return self.stepper.solver

    def with_solver(self, solver):
        return Richardson(self.stepper.with_solver(solver))

    @property
    def order(self) -> int:
        return self.stepper.order

    @property
    def error_order(self) -> int:
        return self.stepper.order + 1

    def step(self, model, t0, h, y0, args):
        # The full step and the first half step start from the same state: one batched
        # (vmapped) copy of the stepper instead of two keeps the compiled program small.
        both = jax.vmap(lambda hh: self.stepper.step(model, t0, hh, y0, args))(
            jnp.stack([h, 0.5 * h])
        )
        full = jax.tree.map(lambda x: x[0], both)
        half1 = jax.tree.map(lambda x: x[1], both)
        half2 = self.stepper.step(model, t0 + 0.5 * h, 0.5 * h, half1.y1, args)
        p = self.stepper.order
        y_error = (half2.y1 - full.y1) / (2.0**p - 1.0)
        stats = StepStats.combine(full.stats, half1.stats, half2.stats)
        return StepOutput(y1=half2.y1, y_error=y_error, multipliers=half2.multipliers, stats=stats)
