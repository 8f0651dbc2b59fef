"""`SaveAt`: what a solve keeps besides its final state."""

from typing import Any

import equinox as eqx


class SaveAt(eqx.Module):
    """What a solve keeps (as diffrax's `SaveAt`). The final state and the counters
    (`Solution.y_final`, `t_final`, `n_accepted`, `result`, ...) are always kept.

    - `steps`: keep every accepted step: `Solution.ts`, `ys`, `hs`, `multipliers`,
      `iterations`, `residual_norms`, `nonlinear_success`, buffers of `max_steps + 1` rows.
      With `False` these fields are `None` and their buffers are not allocated in the loop:
      a sweep of $N$ members then carries no $N \\times$ `max_steps` arrays.
    - `ts`: output times in $[t_0, t_1]$ (as `solve`'s `t_eval`), filled into
      `Solution.y_eval`. Without `steps` they are interpolated inside the loop, each at the
      accepted step that contains it, with the same interpolant as from saved steps.

    `SaveAt()` keeps the final state only (the default of [`nivpjax.solve_batched`][]);
    `SaveAt(ts=ts)` the final state and the states at `ts`; `SaveAt(steps=True)` every step
    (the default of [`nivpjax.solve`][]).
    """

    steps: bool = eqx.field(static=True, default=False)
    ts: Any = None

    def __check_init__(self):
        if not isinstance(self.steps, bool):
            raise TypeError(f"`SaveAt.steps` must be a bool, got {self.steps!r}.")


EVERY_STEP = SaveAt(steps=True)


def resolve(saveat, t_eval, default: SaveAt = EVERY_STEP):
    """`(steps, t_eval)` from `solve`'s `saveat` and `t_eval` arguments: the times come from
    either, not both."""
    if saveat is None:
        saveat = default
    if not isinstance(saveat, SaveAt):
        raise TypeError(f"`saveat` must be an nivpjax.SaveAt, got {saveat!r}.")
    if saveat.ts is not None and t_eval is not None:
        raise ValueError("Output times were given twice: as `t_eval` and as `saveat.ts`; give one.")
    return saveat.steps, (saveat.ts if saveat.ts is not None else t_eval)
