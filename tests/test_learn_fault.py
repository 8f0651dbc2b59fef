"""nivpjax.learn.fault: the study's fault environment on hand-made steps of the 2 x 2 fault.

Reward and observation are recomputed here from the three solves (run directly with the
stepper) and the study's formulas in NumPy; the step-doubling estimate is checked against
`StepDoublingController` on `Richardson`'s step."""

import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
import pytest

import nivpjax as nj
from nivpjax.learn import fault, tasks


DATA = pathlib.Path(__file__).parent / "data"
ALPHA = 8.0


@pytest.fixture(scope="module")
def env():
    # A capped VI solver: the largest steps fail to converge, so rejections are reachable.
    # Without Anderson acceleration: its choice between the extrapolation and the move
    # compares two residuals, which rounding can tip differently in the batched and the
    # single programs, and an unconverged stage keeps that difference (8.6e-6 of a
    # reward, against the 1e-6 to which these tests compare the two).
    stepper = nj.Bathe(solver=nj.FixedPointVI(max_steps=30, anderson=0))
    task = fault.fault_task(DATA / "kijs_2x2elem-3x3length.npy", stepper=stepper, max_steps=50)
    return fault.FaultEnv(task)


_reset = eqx.filter_jit(lambda env, key: env.reset(key))
_step = eqx.filter_jit(lambda env, s, a: env.step(None, s, a, fault.FaultEnvParams(ALPHA)))
_vreset = eqx.filter_jit(lambda env, keys: jax.vmap(env.reset)(keys))
_vstep = eqx.filter_jit(
    lambda env, s, a: jax.vmap(lambda s, a: env.step(None, s, a, fault.FaultEnvParams(ALPHA)))(s, a)
)


# The three solves as the env makes them (the full and the first half step batched: solved
# one by one, the iterates differ at the VI's tolerance, which E amplifies by 1/rtol);
# `test_estimate_matches_step_doubling_controller` checks them against Richardson's.
_solves = eqx.filter_jit(lambda env, t, h, y, args: env.doubling(t, h, y, args))


def _expected(env, state, a, running):
    """The study's reward and observation of one step, from the solves and its formulas."""
    task = env.task
    n = task.scene.n_states // 3
    units = nj.scenes.fault_units(3.0)
    dt_min, dt_max = 1e-6, 6000.0 / units["time_ms"]
    dt = dt_min + a * (dt_max - dt_min)
    t = float(state.t)
    h = min(dt, task.t1 - t)
    args = env.args(state)
    full, half1, half2 = _solves(env, state.t, jnp.asarray(h), state.y, args)
    ok = [bool(o.stats.nonlinear_result == nj.RESULTS.successful) for o in (full, half1, half2)]
    converged = all(ok)
    y_lo, y_hi = np.asarray(full.y1), np.asarray(half2.y1)
    scale = 1e-6 + 1e-3 * np.maximum(np.abs(y_lo), np.abs(y_hi))
    E = np.sqrt(np.mean(((y_lo - y_hi) / (2**1 - 1) / scale) ** 2)) if converged else 0.0
    res = [float(o.stats.residual_norm) for o in (full, half1, half2)]
    res = res[0] + (res[1] if ok[0] else 2.0) + (res[2] if ok[0] and ok[1] else 2.0)
    its = [int(o.stats.iterations) for o in (full, half1, half2)]
    cost = its[0] + (its[1] if ok[0] else 0) + (its[2] if ok[0] and ok[1] else 0)
    if converged:
        running.append(cost)
        lo, hi = min(running), max(running)
        s1 = np.clip((h - dt_min) / (dt_max - dt_min), 0, 1)
        s2 = 1 - (cost - lo) / max(1e-8, hi - lo)
        reward = s1 * s2 * np.exp(-ALPHA * E)
        y = y_hi
    else:
        reward = -(dt - dt_min) / (dt_max - dt_min)
        y = np.asarray(state.y)
    K = np.asarray(args["K"])
    mu0 = float(args["mu_res"] + args["delta_mu"])
    u_c = -np.linalg.solve(K, mu0 * np.asarray(args["sigma"]))
    u = y[n : 2 * n]
    energy = (u @ K @ u) / (u_c @ K @ u_c)
    rate = y[:n].mean() / (0.07 / units["velocity_mm_per_ms"])
    sign = 1.0 if converged else -1.0
    acc = 1 / (1 + E) if converged else 0.0
    obs = [energy, rate, res / 4, float(converged), acc, sign * (dt - dt_min) / (dt_max - dt_min)]
    return reward, np.array(obs), converged, E, cost


def test_reward_and_observation_match_their_definitions(env):
    obs, state = _reset(env, jr.PRNGKey(3))
    # The reset observation: the initial energy is (1 + eps)^2 times that at instability.
    x0, args = env.task.sample(jr.PRNGKey(3))
    K = np.asarray(args["K"])
    mu0 = float(args["mu_res"] + args["delta_mu"])
    u_c = -np.linalg.solve(K, mu0 * np.asarray(args["sigma"]))
    eps = np.asarray(x0)[4:8] / u_c - 1
    assert np.allclose(eps, eps[0], rtol=1e-8) and 1e-6 <= eps[0] <= 1e-4
    np.testing.assert_allclose(obs, [(1 + eps[0]) ** 2, 0, 0.5, 0, 0, -0.5], atol=1e-12)
    running, seen = [], set()
    for a in [1e-3, 3e-3, 1.0, 2e-3, 5e-3]:
        reward, expected, converged, E, cost = _expected(env, state, a, running)
        obs, state, r, done, info = _step(env, state, jnp.array([a]))
        seen.add(converged)
        # E is a small difference of two solves, each exact to rounding of the VI iterates
        # (which differ between compiled programs): 1e-6 of it, where a wrong term is O(1).
        np.testing.assert_allclose(float(r), reward, rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(np.asarray(obs), expected, rtol=1e-6, atol=1e-12)
        assert bool(info["converged"]) == converged and int(info["iterations"]) == cost
        np.testing.assert_allclose(float(info["E"]), E, rtol=1e-6, atol=1e-7)
    assert seen == {True, False}  # both branches of the reward were exercised
    assert int(state.n_accepted) == 4 and int(state.n_rejected) == 1
    # S2: at least one accepted step is neither the cheapest nor the dearest.
    assert len(set(running)) >= 3


def test_estimate_matches_step_doubling_controller(env):
    _, state = _reset(env, jr.PRNGKey(1))
    a = 1e-4
    obs, new, r, done, info = _step(env, state, jnp.array([a]))
    assert bool(info["converged"]) and 0 < float(info["E"]) <= 1
    task = env.task
    model, mask = task.model()
    h = info["h"]
    out = nj.Richardson(task.stepper).step(model, state.t, h, state.y, env.args(state))
    controller = nj.StepDoublingController(rtol=1e-3, atol=1e-6, order=1)
    step_info = nj.StepInfo(
        t0=state.t,
        h=h,
        t1=jnp.asarray(task.t1),
        y0=state.y,
        y1=out.y1,
        y_error=out.y_error,
        error_order=nj.Richardson(task.stepper).error_order,
        stats=out.stats,
        error_mask=mask,
        violation=jnp.zeros(()),
        next_event=jnp.asarray(jnp.inf),
    )
    _, c_state = controller.init(state.t, task.t1, state.y, h, None, 3, mask)
    accept, _, (err, _) = controller.adapt(step_info, c_state)
    assert bool(accept)
    np.testing.assert_allclose(float(err), float(info["E"]), rtol=1e-10)
    np.testing.assert_allclose(np.asarray(new.y), np.asarray(out.y1), rtol=1e-12, atol=1e-12)


def test_vector_env_matches_single(env):
    keys = jr.split(jr.PRNGKey(7), 2)
    actions = jnp.array([[[2e-3], [1.0]], [[4e-3], [3e-3]]])  # (steps, members, 1)
    obs_v, state_v = _vreset(env, keys)
    singles = [_reset(env, k) for k in keys]
    for i, (o, _) in enumerate(singles):
        np.testing.assert_allclose(obs_v[i], o, rtol=1e-12)
    states = [s for _, s in singles]
    for acts in actions:
        obs_v, state_v, r_v, d_v, _ = _vstep(env, state_v, acts)
        for i in range(2):
            o, states[i], r, d, _ = _step(env, states[i], acts[i])
            # Observation 4 and the reward hold E, amplified rounding (see above).
            np.testing.assert_allclose(obs_v[i], o, rtol=1e-6, atol=1e-12)
            np.testing.assert_allclose(r_v[i], r, rtol=1e-6, atol=1e-12)
            np.testing.assert_allclose(state_v.y[i], states[i].y, rtol=1e-9, atol=1e-9)
            assert bool(d_v[i]) == bool(d)


def test_episode_ends_at_t1_and_freezes(env):
    _, state = _reset(env, jr.PRNGKey(2))
    state = eqx.tree_at(lambda s: s.t, state, jnp.asarray(env.task.t1 - 1e-3))
    obs, state, r, done, info = _step(env, state, jnp.array([0.01]))
    assert bool(done) and bool(info["terminated"]) and float(state.t) == env.task.t1
    np.testing.assert_allclose(float(info["h"]), 1e-3, rtol=1e-9)
    obs2, state2, r2, done2, _ = _step(env, state, jnp.array([0.5]))
    assert float(r2) == 0.0 and bool(done2) and int(state2.steps) == int(state.steps)


def test_bad_input():
    with pytest.raises(ValueError, match="Dc"):
        fault.fault_task(DATA / "kijs_1x1elem-3x3length.npy", Dc=(2.0, 1.0))
    with pytest.raises(TypeError, match="fault_task"):
        fault.FaultEnv(tasks.relay_sliding())


def test_spectral_kernel_energy():
    # The observation's energy with the FFT kernel against the dense matrix of the same
    # symbol (built column by column in NumPy); the slip-rate feature against its formula.
    env = fault.FaultEnv(fault.fault_task("spectral", 3, 2, max_steps=5))
    _, state = env.reset(jr.PRNGKey(0))
    args = env.args(state)
    n = 6
    symbol = np.asarray(args["symbol"])
    K = np.stack([nj_spectral(symbol, e) for e in np.eye(n)], axis=1)
    y = np.asarray(jr.normal(jr.PRNGKey(1), (3 * n,)))
    energy, rate = env._physics(jnp.asarray(y), args, 2.0)
    np.testing.assert_allclose(float(energy), 0.5 * y[n : 2 * n] @ K @ y[n : 2 * n] / 2.0)
    v_unit = nj.scenes.fault_units(3.0)["velocity_mm_per_ms"]
    np.testing.assert_allclose(float(rate), y[:n].mean() / (0.07 / v_unit))


def nj_spectral(symbol, u):
    from nivpjax._elastic import spectral_apply_np

    return spectral_apply_np(symbol, u, 3, 2)
