"""gymnasium wrappers of the functional step-size environment: one compiled `reset` and
`step`, and a vector environment that steps a whole batch in one compiled call."""

import dataclasses
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .._compiler import filter_jit
from .._results import RESULTS
from ..learn import EnvParams, Objective, StepSizeEnv, Task
from ..learn.tasks import TASKS


_FEATURE_BOUND = 30.0  # every feature of StepFeatures lies within +-25


def _functional(task, action_mode, objective, task_kwargs):
    """The functional env, and the episode length: the task's `max_steps` actions. The
    task's budget counts attempts, `reset`'s first one (PID's initial step) included, which
    left an agent `max_steps - 1` actions: the env gets one more attempt."""
    if isinstance(task, str):
        if task not in TASKS:
            raise ValueError(f"`task` must be one of {sorted(TASKS)} or a Task, got {task!r}.")
        task = TASKS[task](**task_kwargs)
    elif not isinstance(task, Task):
        raise TypeError(f"`task` must be a task name or a nivpjax.learn.Task, got {task!r}.")
    actions = task.max_steps
    env = StepSizeEnv(dataclasses.replace(task, max_steps=actions + 1), action_mode=action_mode)
    return env, EnvParams(Objective() if objective is None else objective), actions


def _result(result, i=None):
    """The message of a result code (of member `i` of a batch of them)."""
    return RESULTS[result if i is None else jax.tree.map(lambda v: v[i], result)]


def _spaces(env: StepSizeEnv):
    dtype = np.dtype(jnp.zeros(()).dtype)
    obs = spaces.Box(-_FEATURE_BOUND, _FEATURE_BOUND, (env.obs_size,), dtype)
    lo, hi = env.action_bounds
    act = spaces.Box(np.float32(lo), np.float32(hi), (1,), np.float32)
    return obs, act


@filter_jit
def _reset(env, key, params):
    return env.reset(key, params)


@filter_jit
def _step(env, state, action, params):
    return env.step(jr.PRNGKey(0), state, action, params)


@filter_jit
def _vreset(env, keys, params):
    return jax.vmap(env.reset, in_axes=(0, None))(keys, params)


@filter_jit
def _vstep(env, state, actions, params):
    return jax.vmap(env.step, in_axes=(None, 0, 0, None))(jr.PRNGKey(0), state, actions, params)


def _key(np_random):
    return jr.PRNGKey(int(np_random.integers(0, 2**31 - 1)))


class StepSizeGymEnv(gymnasium.Env):
    """A `gymnasium.Env` over [`nivpjax.learn.StepSizeEnv`][] (registered as
    `"nivpjax/StepSize-v0"`).

    - observation: the features of the last attempt ([`nivpjax.StepFeatures`][]);
    - action: `Box(-1, 1, (1,))`, the normalised log step factor (`action_mode="log_factor"`),
      or `Box(0, 1, (1,))` mapped to `[h_min, h_max]` (`action_mode="absolute"`, the
      reference environment's convention);
    - reward: minus the [`nivpjax.learn.Objective`][] (work per attempt; accuracy at the end);
    - `reset(seed=...)` draws scene parameters (and solves the reference);
    - `terminated` at `t1` or on a failure; `truncated` after `max_episode_steps` steps
      (default: the task's `max_steps`; the attempt `reset` makes with PID's initial step
      does not count);
    - `info`: `t`, `h` and `error` of the attempt, `failed` (the solve failed: `h_min`
      reached or the nonlinear solve failed) and `result`, the solve's
      [`nivpjax.RESULTS`][] message (`"successful"` unless it failed).

    **Arguments:** `task` (a name of `nivpjax.learn.tasks.TASKS` or a
    [`nivpjax.learn.Task`][]), `action_mode`, `objective`, `max_episode_steps`, and
    keyword arguments for the named task (e.g. `t1`).
    """

    metadata = {"render_modes": []}

    def __init__(
        self,
        task: str | Task = "relay_sliding",
        *,
        action_mode: str = "log_factor",
        objective: Objective | None = None,
        max_episode_steps: int | None = None,
        **task_kwargs: Any,
    ):
        self.env, self.params, actions = _functional(task, action_mode, objective, task_kwargs)
        self.observation_space, self.action_space = _spaces(self.env)
        self.max_episode_steps = max_episode_steps or actions
        self._state = None

    def _obs(self, obs):
        return np.clip(np.asarray(obs), -_FEATURE_BOUND, _FEATURE_BOUND).astype(
            self.observation_space.dtype
        )

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        obs, self._state = _reset(self.env, _key(self.np_random), self.params)
        return self._obs(obs), {}

    def step(self, action):
        if self._state is None:
            raise RuntimeError("call reset() before step().")
        action = np.asarray(action, np.float32).reshape(1)
        obs, self._state, reward, _, info = _step(
            self.env, self._state, jnp.asarray(action), self.params
        )
        terminated = bool(info["terminated"]) or bool(self._state.done and not info["truncated"])
        truncated = bool(info["truncated"]) or (
            not terminated and int(self._state.steps) >= self.max_episode_steps
        )
        extra = {"t": float(info["t"]), "h": float(info["h"]), "error": float(info["error"])}
        extra["failed"] = bool(info["failed"])
        extra["result"] = _result(self._state.loop.result)
        return self._obs(obs), float(reward), terminated, truncated, extra


class StepSizeVectorEnv(VectorEnv):
    """`num_envs` step-size environments stepped in one compiled, vmapped call (autoreset
    on the step after an episode ends, gymnasium's `NEXT_STEP` mode). Member `i` of
    `reset(seed=s)` is the single environment reset with `seed=s + i`; `info` holds arrays
    of the single environment's entries."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int,
        task: str | Task = "relay_sliding",
        *,
        action_mode: str = "log_factor",
        objective: Objective | None = None,
        max_episode_steps: int | None = None,
        **task_kwargs: Any,
    ):
        if not (isinstance(num_envs, int) and num_envs >= 1):
            raise ValueError(f"`num_envs` must be a positive int, got {num_envs!r}.")
        self.num_envs = num_envs
        self.env, self.params, actions = _functional(task, action_mode, objective, task_kwargs)
        self.single_observation_space, self.single_action_space = _spaces(self.env)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.max_episode_steps = max_episode_steps or actions
        self._state = None
        self._rngs = None
        self._autoreset = np.zeros(num_envs, bool)

    def _obs(self, obs):
        return np.clip(np.asarray(obs), -_FEATURE_BOUND, _FEATURE_BOUND).astype(
            self.single_observation_space.dtype
        )

    def _keys(self, members):
        # Only members that reset draw from their generator, as a single env would.
        return jnp.stack(
            [_key(self._rngs[i]) if i in members else jr.PRNGKey(0) for i in range(self.num_envs)]
        )

    def reset(self, *, seed=None, options=None):
        if seed is None:
            seed = int(np.random.SeedSequence().generate_state(1)[0])
        self._rngs = [seeding.np_random(seed + i)[0] for i in range(self.num_envs)]
        obs, self._state = _vreset(self.env, self._keys(set(range(self.num_envs))), self.params)
        self._autoreset[:] = False
        return self._obs(obs), {}

    def step(self, actions):
        if self._state is None:
            raise RuntimeError("call reset() before step().")
        actions = jnp.asarray(np.asarray(actions, np.float32).reshape(self.num_envs, 1))
        obs, state, reward, _, info = _vstep(self.env, self._state, actions, self.params)
        reward = np.asarray(reward, np.float64)
        terminated = np.asarray(info["terminated"]) | (
            np.asarray(state.done) & ~np.asarray(info["truncated"])
        )
        truncated = np.asarray(info["truncated"]) | (
            ~terminated & (np.asarray(state.steps) >= self.max_episode_steps)
        )
        failed = np.asarray(info["failed"])
        if self._autoreset.any():
            members = set(np.flatnonzero(self._autoreset).tolist())
            fresh_obs, fresh = _vreset(self.env, self._keys(members), self.params)
            mask = jnp.asarray(self._autoreset)

            def pick(a, b):
                return jnp.where(mask.reshape((-1,) + (1,) * (a.ndim - 1)), a, b)

            state = jax.tree.map(pick, fresh, state)
            obs = pick(fresh_obs, obs)
            reward = np.where(self._autoreset, 0.0, reward)
            terminated = np.where(self._autoreset, False, terminated)
            truncated = np.where(self._autoreset, False, truncated)
            failed = np.where(self._autoreset, False, failed)
        self._state = state
        self._autoreset = terminated | truncated
        extra = {"t": np.asarray(info["t"]), "h": np.asarray(info["h"])}
        extra["error"] = np.asarray(info["error"])
        extra["failed"] = failed
        extra["result"] = np.array([_result(state.loop.result, i) for i in range(self.num_envs)])
        return self._obs(obs), reward, terminated, truncated, extra
