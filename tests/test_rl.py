"""nivpjax.rl: gymnasium's checker, registration, the vector env against the single env,
and the episode return against the objective of the equivalent solve."""

import math
import warnings

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import nivpjax as nv
import nivpjax.rl  # noqa: F401  (registers the environment)
from nivpjax import learn
from nivpjax.rl import StepSizeGymEnv, StepSizeVectorEnv


KW = dict(task="relay_sliding", t1=0.5, max_steps=200)


@pytest.fixture(scope="module")
def env():
    return StepSizeGymEnv(**KW)


def test_check_env(env):
    check_env(env, skip_render_check=True)


def test_registered():
    made = gymnasium.make("nivpjax/StepSize-v0", **KW)
    assert isinstance(made.unwrapped, StepSizeGymEnv)
    assert made.action_space.shape == (1,)


def test_absolute_action_mode():
    env = StepSizeGymEnv(action_mode="absolute", **KW)
    assert env.action_space.low[0] == 0.0 and env.action_space.high[0] == 1.0
    env.reset(seed=3)
    _, reward, terminated, truncated, info = env.step(np.array([0.01], np.float32))
    lo, hi = env.env.h_range
    assert math.isclose(info["h"], lo + 0.01 * (hi - lo), rel_tol=1e-6)
    assert np.isfinite(reward)


def test_vector_env_matches_single(env):
    vec = StepSizeVectorEnv(2, **KW)
    obs_v, _ = vec.reset(seed=10)
    singles = [StepSizeGymEnv(**KW) for _ in range(2)]
    obs_s = [s.reset(seed=10 + i)[0] for i, s in enumerate(singles)]
    # Round-off only: vmapped kernels may order operations differently, and feature 0 is the
    # log of an error estimate (a difference of nearly equal stage values); measured 3e-11.
    np.testing.assert_allclose(obs_v, np.stack(obs_s), rtol=1e-10)
    actions = np.array([[0.3, -0.2], [0.1, 0.5], [-0.4, 0.2], [0.2, 0.2]], np.float32)
    for a in actions:
        obs_v, rew_v, term_v, trunc_v, _ = vec.step(a[:, None])
        for i, s in enumerate(singles):
            obs, rew, term, trunc, _ = s.step(a[i : i + 1])
            np.testing.assert_allclose(obs_v[i], obs, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(rew_v[i], rew, rtol=1e-10)
            assert term_v[i] == term and trunc_v[i] == trunc


def test_episode_return_is_minus_objective(env):
    """Acting with the (rescaled) integral policy in the env reproduces the solve with
    PolicyController: the same attempts, and rewards summing to minus the objective."""
    fenv = env.env
    task = fenv.task
    scale = fenv.action_scale
    policy = nv.IntegralPolicy(task.full_stepper.error_order)
    obs, _ = env.reset(seed=5)
    total, done, steps = 0.0, False, 0
    while not done:
        action = np.asarray(policy(jnp.asarray(obs)), np.float32) / scale
        obs, reward, terminated, truncated, _ = env.step(action)
        total += reward
        done = terminated or truncated
        steps += 1
    state = env._state
    controller = task.policy_controller(policy)  # action_scale 1: the same log factor
    sol = task.solve(controller, state.x0, state.args)
    m = learn.metrics(task, env.params.objective, sol, state.y_ref)
    assert int(state.loop.n_attempts) == int(m.attempts) == steps + 1
    np.testing.assert_allclose(total, -float(m.cost), rtol=1e-6)


def test_truncated_after_max_steps_actions():
    """`truncated` comes with the task's `max_steps`-th step (it came one step early: the
    task's budget counted `reset`'s attempt). Absolute action 0 steps by h_min: never done.
    The environment of `test_absolute_action_mode` (its compiled programs)."""
    env = StepSizeGymEnv(action_mode="absolute", **KW)
    env.reset(seed=0)
    n = KW["max_steps"]
    flags = [env.step(np.zeros(1, np.float32))[2:4] for _ in range(n)]
    assert flags[-1] == (False, True) and not any(any(f) for f in flags[:-1])
    assert int(env._state.steps) == n and int(env._state.loop.n_attempts) == n + 1


def test_float32_reset_is_quiet_and_failures_are_in_info():
    """In float32 (JAX's default), `reset` warned `overflow encountered in cast` (a 1e300 in
    the features), and a random-action episode ended `terminated` at t = 0.6 of 3 with no
    word of the failure: `info` now says it (here `h_min`, float32's floor on the step)."""
    jax.config.update("jax_enable_x64", False)
    try:
        env = StepSizeGymEnv(task="relay_sliding")
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            env.reset(seed=0)
        env.action_space.seed(0)
        for _ in range(env.max_episode_steps):
            _, _, terminated, truncated, info = env.step(env.action_space.sample())
            if terminated or truncated:
                break
    finally:
        jax.config.update("jax_enable_x64", True)
    assert terminated and info["t"] < 3.0
    assert info["failed"] and info["result"] == nv.RESULTS[nv.RESULTS.h_min_reached]
