r"""A gymnax `Environment` over nivpjax's functional step-size environments, so that
gymnax-based agents (rejax's SAC, PPO, TD3) train on them inside one compiled program.

Needs the optional extra `pip install "nivpjax[rl]"` (gymnax < 1 and rejax: rejax 0.1.3
unpacks gymnax's old five-value `step`, which gymnax 1.0 changed to six values). Import
it explicitly: `from nivpjax.rl.gymnax_env import GymnaxEnv`; `nivpjax.rl` itself needs
only gymnasium."""

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
from gymnax.environments import environment, spaces

from ..learn import FaultEnv, StepSizeEnv


class GymnaxParams(eqx.Module):
    """gymnax's environment parameters: the wrapped environment's own (`inner`) and
    `max_steps_in_episode` (gymnax's and rejax's episode bound, e.g. for evaluation)."""

    inner: Any
    max_steps_in_episode: int = eqx.field(static=True)


class GymnaxEnv(environment.Environment):
    r"""A `gymnax.environments.environment.Environment` over a functional environment:
    [`nivpjax.learn.FaultEnv`][] (the study's, whose `reset` is cheap) or
    [`nivpjax.learn.StepSizeEnv`][].

    gymnax's `step(key, state, action, params) -> (obs, state, reward, done, info)` resets
    a finished episode automatically; it evaluates `reset_env` at every step and selects.
    For `FaultEnv` a reset is a parameter draw and one observation; `StepSizeEnv`'s reset
    solves the tight reference, so each of its steps costs a reference solve: prefer
    `FaultEnv`, or the functional `StepSizeEnv` without this wrapper.

    - observation space: `Box(-inf, inf, (obs_size,))`; action space: `Box(lo, hi, (1,))`
      with the environment's `action_bounds` (`[0, 1]` for `FaultEnv`);
    - `default_params`: [`nivpjax.rl.gymnax_env.GymnaxParams`][] of the environment's default
      parameters and `max_steps_in_episode` (default: the environment's episode length);
    - `is_terminal(state, params)`: the episode is done (at $t_1$, or truncated).

    Instances hash by identity (gymnax jits `step` with the environment static).
    """

    def __init__(self, env: FaultEnv | StepSizeEnv, params=None, max_steps_in_episode=None):
        if not isinstance(env, (FaultEnv, StepSizeEnv)):
            raise TypeError(f"`env` must be a FaultEnv or a StepSizeEnv, got {env!r}.")
        self.env = env
        if max_steps_in_episode is None:
            max_steps_in_episode = (
                env.episode_steps if isinstance(env, FaultEnv) else env.task.max_steps
            )
        self._params = GymnaxParams(
            env.default_params() if params is None else params, int(max_steps_in_episode)
        )

    @property
    def default_params(self) -> GymnaxParams:
        return self._params

    def step_env(self, key, state, action, params: GymnaxParams):
        obs, state, reward, done, info = self.env.step(key, state, action, params.inner)
        return obs, state, reward, done, info

    def reset_env(self, key, params: GymnaxParams):
        return self.env.reset(key, params.inner)

    def get_obs(self, state, params=None, key=None):
        if isinstance(self.env, FaultEnv):
            return state.obs
        return self.env.observe(state)

    def is_terminal(self, state, params=None):
        return state.done

    def returns(self, act, keys, episode=None, params=None):
        """The return of `act(obs, key) -> action` in one episode per key of `keys` (a
        batch of PRNG keys): the rewards summed from a reset up to the end of the wrapped
        environment's episode (no automatic reset), over at most `episode` steps (default
        `max_steps_in_episode`). Jittable, e.g. as rejax's `eval_callback`."""
        params = self.default_params if params is None else params
        episode = params.max_steps_in_episode if episode is None else int(episode)

        def one(key):
            obs, state = self.reset(key, params)

            def body(carry, k):
                obs, state, total, alive = carry
                obs, state, r, d, _ = self.env.step(k, state, act(obs, k), params.inner)
                return (obs, state, total + jnp.where(alive, r, 0.0), alive & ~d), None

            init = (obs, state, jnp.zeros(()), jnp.ones((), bool))
            (_, _, total, _), _ = jax.lax.scan(body, init, jr.split(key, episode))
            return total

        return jax.vmap(one)(keys)

    @property
    def name(self) -> str:
        return f"nivpjax-{type(self.env).__name__}"

    @property
    def num_actions(self) -> int:
        return 1

    def action_space(self, params=None):
        lo, hi = self.env.action_bounds
        return spaces.Box(lo, hi, (1,), jnp.zeros(()).dtype)

    def observation_space(self, params=None):
        return spaces.Box(-jnp.inf, jnp.inf, (self.env.obs_size,), jnp.zeros(()).dtype)
