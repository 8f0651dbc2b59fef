"""The step-size environment as pure functions (gymnax's convention), over the loop's own
`init_state`/`attempt`: training in the graph and from the host see the same environment."""

import math
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr

from .._controller import PolicyController
from .._loop import _LoopState, attempt, finish, init_state, interpolate
from .._results import RESULTS
from ._task import Objective, Task, scaled_error


class _Hold(eqx.Module):
    """The env's controller only tests errors and computes features; actions set `h`."""

    def __call__(self, features):
        return jnp.zeros((1,), features.dtype)


class EnvParams(eqx.Module):
    """Environment parameters: the objective whose negative is the reward."""

    objective: Objective = Objective()


class EnvState(eqx.Module):
    """One episode: the loop state, the draw, its reference, and bookkeeping."""

    loop: _LoopState
    x0: Any
    args: Any
    y_ref: Any
    pending: Any  # the cost of the attempt made in `reset`, paid with the first reward
    done: Any
    steps: Any


class StepSizeEnv(eqx.Module):
    r"""A functional environment for step-size control (gymnax's convention).

    - `reset(key, params) -> (obs, state)`: draws `(x0, args)` with `task.sample(key)`,
      solves the tight reference, and makes the first attempt with the PID estimate of
      $h_0$; `obs` are its features ([`nivpjax.StepFeatures`][]).
    - `step(key, state, action, params) -> (obs, state, reward, done, info)`: sets the next
      step from `action`, makes one attempt (accepted by the error test) and returns its
      features. `reward` is minus the [`nivpjax.learn.Objective`][]: each attempt costs its
      work; the episode's end adds the accuracy term (at `t1`) or the failure cost
      (`h_min`, nonlinear failure, or `max_steps` attempts: `info["truncated"]`). Summed
      over an episode, the rewards are minus the objective of the equivalent
      [`nivpjax.solve`][] with a [`nivpjax.PolicyController`][]. After `done`, steps change
      nothing and return reward 0. `info`: `terminated`, `truncated`, `failed` (the solve
      failed: `h_min` or the nonlinear solve; the code is `state.loop.result`), the
      accuracy term's `error`, and `t`, `h` of the attempt.

    **Arguments:**

    - `task`: a [`nivpjax.learn.Task`][].
    - `action_mode`: `"log_factor"` (default): `action` in $[-1, 1]$, the next step is
      $h \exp(\text{action\_scale}\cdot a)$ with PID's rails (`PolicyController.step_factor`);
      `"absolute"`: the reference environment's convention, `action` in $[0, 1]$ mapped
      linearly to $[h_{\min}, h_{\max}]$ (no rails).
    - `action_scale`: $\log 10$ by default (a = 1 multiplies the step by 10).
    - `h_min`, `h_max`: the range of `"absolute"` actions (default: `(t1 - t0)` times
      1e-6 and 0.1).
    """

    task: Task
    action_mode: Literal["log_factor", "absolute"] = eqx.field(static=True, default="log_factor")
    action_scale: float = math.log(10.0)
    h_min: float | None = None
    h_max: float | None = None

    def __check_init__(self):
        if self.action_mode not in ("log_factor", "absolute"):
            raise ValueError(
                f"`action_mode` must be 'log_factor' or 'absolute', got {self.action_mode!r}."
            )

    @property
    def controller(self) -> PolicyController:
        return self.task.policy_controller(_Hold(), action_scale=self.action_scale)

    @property
    def obs_size(self) -> int:
        return self.controller.feature_map.size

    @property
    def action_bounds(self):
        return (-1.0, 1.0) if self.action_mode == "log_factor" else (0.0, 1.0)

    @property
    def h_range(self):
        span = self.task.t1 - self.task.t0
        lo = 1e-6 * span if self.h_min is None else self.h_min
        hi = 0.1 * span if self.h_max is None else self.h_max
        return lo, hi

    def default_params(self) -> EnvParams:
        return EnvParams()

    def _attempt(self, loop, args):
        model, mask = self.task.model()
        t1 = jnp.asarray(self.task.t1, loop.y.dtype)
        return attempt(loop, model, self.task.full_stepper, self.controller, t1, args, mask)

    def _work(self, before, after, params):
        dtype = after.y.dtype
        return params.objective.work(
            jnp.ones((), dtype),
            (after.n_iterations - before.n_iterations).astype(dtype),
            (after.n_rejected - before.n_rejected).astype(dtype),
        )

    def reset(self, key, params: EnvParams | None = None):
        params = self.default_params() if params is None else params
        task = self.task
        x0, args = task.sample(key)
        y0 = task.scene.initial_state(jnp.asarray(x0))
        y_ref, _ = task.reference(x0, args)
        model, mask = task.model()
        dtype = y0.dtype
        t0, t1 = jnp.asarray(task.t0, dtype), jnp.asarray(task.t1, dtype)
        loop = init_state(
            model, task.full_stepper, self.controller, t0, t1, y0, args, None, mask,
            task.max_steps, False,
        )  # fmt: skip
        first = self._attempt(loop, args)
        state = EnvState(
            loop=first,
            x0=x0,
            args=args,
            y_ref=y_ref,
            pending=self._work(loop, first, params),
            done=jnp.zeros((), bool),
            steps=jnp.zeros((), jnp.int32),
        )
        state = eqx.tree_at(lambda s: s.done, state, self._finished(first)[0])
        return self.observe(state), state

    def observe(self, state: EnvState):
        return state.loop.controller_state.features

    def _finished(self, loop):
        task = self.task
        at_end = loop.t >= task.t1
        failed = loop.result != RESULTS.successful
        truncated = ~at_end & ~failed & (loop.n_attempts >= task.max_steps)
        return at_end | failed | truncated, at_end, failed, truncated

    def _next_h(self, loop, action):
        action = jnp.asarray(action, loop.y.dtype).reshape(-1)[0]
        controller = self.controller
        if self.action_mode == "log_factor":
            a = jnp.clip(action, -1.0, 1.0)
            h = loop.h_last * controller.step_factor(a, loop.controller_state)
        else:
            lo, hi = self.h_range
            h = lo + jnp.clip(action, 0.0, 1.0) * (hi - lo)
        h_max = controller.bounds[1]
        if h_max is not None:
            h = jnp.minimum(h, h_max)
        return jnp.maximum(h, loop.h_min)

    def terminal_cost(self, state: EnvState, params: EnvParams):
        """The accuracy term at `t1`, or the failure cost."""
        _, at_end, _, _ = self._finished(state.loop)
        sol = finish(state.loop, jnp.asarray(self.task.t1, state.loop.y.dtype))
        model, _ = self.task.model()
        y_eval = interpolate(sol, self.task.t_eval, model, state.args)
        error = scaled_error(self.task, y_eval, state.y_ref)
        objective = params.objective
        return jnp.where(at_end, objective.accuracy(error), objective.failure), error

    def step(self, key, state: EnvState, action, params: EnvParams | None = None):
        del key  # the environment is deterministic given the draw
        params = self.default_params() if params is None else params
        loop = eqx.tree_at(lambda s: s.h, state.loop, self._next_h(state.loop, action))
        new = self._attempt(loop, state.args)
        done, at_end, failed, truncated = self._finished(new)
        cost = self._work(state.loop, new, params) + state.pending
        candidate = EnvState(
            loop=new,
            x0=state.x0,
            args=state.args,
            y_ref=state.y_ref,
            pending=jnp.zeros_like(state.pending),
            done=done,
            steps=state.steps + 1,
        )
        terminal, error = self.terminal_cost(candidate, params)
        cost = cost + jnp.where(done, terminal, 0.0)
        # A finished episode stays as it is.
        keep = state.done
        out = jax.tree.map(lambda old, x: jnp.where(keep, old, x), state, candidate)
        reward = jnp.where(keep, 0.0, -cost)
        info = {
            "terminated": (at_end | failed) & ~keep,
            "truncated": truncated & ~keep,
            "failed": failed & ~keep,
            "error": error,
            "t": out.loop.t,
            "h": out.loop.h_last,
        }
        return self.observe(out), out, reward, out.done, info


def random_actions(env: StepSizeEnv, key, n):
    """`n` uniform actions in the env's action box (for tests and baselines)."""
    lo, hi = env.action_bounds
    return jr.uniform(key, (n,), minval=lo, maxval=hi)
