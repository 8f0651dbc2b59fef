"""What `solve` returns."""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ._results import RESULTS


class StepStats(eqx.Module):
    """Diagnostics of one attempted step, handed to the controller as one object.

    - `iterations`: nonlinear iterations summed over the step's stages.
    - `residual_norm`: the largest final nonlinear residual over the stages.
    - `nonlinear_result`: the first failure among the stages (or `successful`).
    """

    iterations: Int[Array, ""]
    residual_norm: Float[Array, ""]
    nonlinear_result: RESULTS

    @staticmethod
    def combine(*stats: "StepStats") -> "StepStats":
        result = stats[0].nonlinear_result
        for s in stats[1:]:
            result = RESULTS.where(result == RESULTS.successful, s.nonlinear_result, result)
        return StepStats(
            iterations=sum(s.iterations for s in stats),
            residual_norm=jnp.max(jnp.stack([s.residual_norm for s in stats])),
            nonlinear_result=result,
        )


class AttemptLog(eqx.Module):
    """Every attempted step (`save_attempts=True`), in order; entries past `n_attempts` of
    the solution are padding (`t = inf`)."""

    t: Float[Array, " k"]
    h: Float[Array, " k"]
    accepted: Bool[Array, " k"]
    error_norm: Float[Array, " k"]
    iterations: Int[Array, " k"]
    nonlinear_success: Bool[Array, " k"]


class Solution(eqx.Module):
    """The result of [`nivpjax.solve`][].

    Buffers have `max_steps + 1` rows (or are `None`: steps not saved,
    [`nivpjax.SaveAt`][]`(steps=False)`, the default of [`nivpjax.solve_batched`][]); the
    first `n_accepted + 1` are the initial point and the accepted steps, the rest are
    padding (`t = inf`; states and multipliers repeat the
    last accepted value so that plots and reductions stay finite; step sizes, iterations
    and residual norms are 0, `nonlinear_success` True). Use
    [`nivpjax.Solution.trimmed`][] on concrete results to drop the padding.

    - `ts`, `ys`: accepted times and states.
    - `hs`: the step that produced each accepted state (entry 0 is the initial step size).
    - `multipliers`: the implicit residual at each accepted state (reference: `fk`): the
      constraint reaction per unit time, e.g. contact impulse / h, friction force, relay
      multiplier's row; zero (to solver tolerance) on free components.
    - `iterations`, `residual_norms`, `nonlinear_success`: per accepted step.
    - `t_final`, `y_final`: where the run ended (`t1` unless it failed).
    - `h_last`: the size of the last attempted step (the failing one if the run failed).
    - `n_accepted`, `n_rejected`, `n_iterations`: counts (iterations include rejected steps).
    - `result`: a [`nivpjax.RESULTS`][] code.
    - `t_eval`, `y_eval`: the solution at the requested output times (cubic Hermite
      interpolation between accepted steps on differential rows, with projected rates and
      values on rows a set constrains; linear on algebraic rows), or `None`.
    - `multipliers_eval`: the constraint reactions at `t_eval` (as `multipliers`, units
      of $f$: a force, per unit mass where $f$ is an acceleration; never an impulse),
      each inside its set (a box's normal force at a face, zero off it; a friction force
      within its bound, bit for bit on an interval; a contact's force zero in flight and
      the resting force where the contact holds the body), or `None`. They are the
      reactions the interpolated state takes: the stepper's order inside a phase, split
      where a phase begins or ends inside a step. An impact is an impulse and has no
      force at an instant (the `multipliers` row of its step holds impulse / h).
      Selections that are states (a relay's $w$ on an algebraic row) are in `y_eval`, by
      the same rule: the projected equivalent control in a sliding mode, the start's
      value until the switching function changes sign, $|w| \\le 1$ bit for bit.
    - `attempts`: an [`nivpjax.AttemptLog`][] or `None`.
    """

    ts: Float[Array, " N"] | None
    ys: Float[Array, "N n"] | None
    hs: Float[Array, " N"] | None
    multipliers: Float[Array, "N n"] | None
    iterations: Int[Array, " N"] | None
    residual_norms: Float[Array, " N"] | None
    nonlinear_success: Bool[Array, " N"] | None
    t_final: Float[Array, ""]
    h_last: Float[Array, ""]
    y_final: Float[Array, " n"]
    n_accepted: Int[Array, ""]
    n_rejected: Int[Array, ""]
    n_iterations: Int[Array, ""]
    result: RESULTS
    t_eval: Float[Array, " m"] | None = None
    y_eval: Float[Array, "m n"] | None = None
    attempts: AttemptLog | None = None
    multipliers_eval: Float[Array, "m n"] | None = None

    def trimmed(self) -> "Solution":
        """A copy with buffers cut to the accepted steps (needs concrete, unbatched values)."""
        k = int(self.n_accepted) + 1
        cut = lambda x: None if x is None else x[:k]
        attempts = self.attempts
        return Solution(
            ts=cut(self.ts),
            ys=cut(self.ys),
            hs=cut(self.hs),
            multipliers=cut(self.multipliers),
            iterations=cut(self.iterations),
            residual_norms=cut(self.residual_norms),
            nonlinear_success=cut(self.nonlinear_success),
            t_final=self.t_final,
            h_last=self.h_last,
            y_final=self.y_final,
            n_accepted=self.n_accepted,
            n_rejected=self.n_rejected,
            n_iterations=self.n_iterations,
            result=self.result,
            t_eval=self.t_eval,
            y_eval=self.y_eval,
            attempts=attempts,
            multipliers_eval=self.multipliers_eval,
        )
