"""Consistent initial multipliers (`Model.consistent_initial_state`): a reaction that acts
through the velocity starts at its physical value, so the trapezoidal rule does not ring.

The block sliding to rest on a plane, contact and friction in one second-order cone
(`nj.scenes.block_on_plane(cone=True)`): exactly, the normal reaction is $g$ throughout and
the friction reaction $-\\mu g\\, v_0/|v_0|$ until the stop at $t^* = |v_0|/(\\mu g)$."""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import nivpjax as nj


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
from _references_mechanics import block_state  # noqa: E402


G = 9.81
T1 = 2.0
GRID = ({"mu": 0.3, "v": (2.0, 1.0)}, {"mu": 0.6, "v": (1.0, -3.0)}, {"mu": 0.15, "v": (-0.5, 0.2)})
RTOLS = (1e-4, 1e-5, 1e-6)


@pytest.fixture(scope="module")
def run():
    scene, _, _ = nj.scenes.block_on_plane(cone=True)

    @jax.jit
    def solve(x0, args, rtol):
        return scene.solve(
            0.0,
            T1,
            x0,
            args,
            stepper=nj.Trapezoidal(),
            controller=nj.PIDController(rtol=rtol, atol=rtol / 100),
            max_steps=4096,
            throw=False,
        )

    def go(p, rtol):
        _, x0, args = nj.scenes.block_on_plane(mu=p["mu"], velocity=p["v"], cone=True)
        return scene, solve(x0, args, rtol)

    return go


def _error(p, sol, scene):
    k = int(sol.n_accepted)
    ts = np.asarray(sol.ts[: k + 1])
    xs, _ = scene.split(np.asarray(sol.ys[: k + 1]))
    pos, vel, _ = block_state(ts, p["v"], p["mu"], G)
    zero = np.zeros((len(ts), 1))
    return np.max(np.abs(xs - np.concatenate([pos, zero, vel, zero], axis=-1)))


@pytest.mark.parametrize("p", GRID)
def test_initial_reaction_is_the_physical_one(run, p):
    scene, sol = run(p, 1e-5)
    _, m = scene.split(np.asarray(sol.ys[0]))
    v = np.asarray(p["v"])
    expected = np.concatenate([[G], -p["mu"] * G * v / np.linalg.norm(v)])
    np.testing.assert_allclose(m["lam"], expected, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("p", GRID)
def test_trapezoidal_cone_normal_force_does_not_ring(run, p):
    # Every step's normal reaction is g (before: 0 and 2g alternately), and the error
    # falls with rtol within 10 rtol^(2/3) (the campaign's bound for a second-order
    # stepper through the stop, where the reaction jumps).
    errors = []
    for rtol in RTOLS:
        scene, sol = run(p, rtol)
        assert sol.result == nj.RESULTS.successful
        k = int(sol.n_accepted)
        _, m = scene.split(np.asarray(sol.ys[: k + 1]))
        np.testing.assert_allclose(m["lam"][:, 0], G, rtol=1e-8)
        assert k < 200
        errors.append(_error(p, sol, scene))
        assert errors[-1] <= 10 * rtol ** (2 / 3)
    assert errors[-1] < 0.2 * errors[0]


def test_relay_started_on_its_surface_takes_the_equivalent_control():
    # x' = -w + a sin(t) from x0 = 0 with |a| < 1: it slides from the start, and the
    # selection's consistent value is the equivalent control w = a cos(0) = a at
    # t0 (O(h): it is backward Euler's w over the first step); the first stage alone
    # left it at its initial guess whatever that was.
    def dynamics(t, x, a, m):
        return -m["w"] + a["a"] * jnp.cos(t)

    scene = nj.Scene(dynamics, 1, (nj.Relay("w", lambda t, x, a: x),))
    x0 = jnp.zeros(1)
    args = {"a": jnp.asarray(0.5)}
    control = nj.PIDController(rtol=1e-6, atol=1e-8)
    sol = scene.solve(0.0, 1.0, x0, args, multipliers={"w": jnp.asarray([0.9])}, controller=control)
    _, m = scene.split(np.asarray(sol.ys[0]))
    h = float(sol.ts[1] - sol.ts[0])
    assert abs(m["w"][0] - 0.5) <= 0.5 * h + 1e-12


def test_trapezoidal_cone_with_a_push_as_the_smooth_field():
    # Issue 32's disk law as cone friction (mu g = 1, a rotating push, |v| >= 0.48): with
    # consistent multipliers the trapezoidal rule takes the steps of the same law written
    # into f (before: 10 935 steps against 433 at rtol 1e-5), at the same error.
    scene, x0, args = nj.scenes.block_on_plane(
        mu=1.0 / G, gravity=G, velocity=(0.5, 0.3), cone=True, push=(1.5, 2.0)
    )

    def smooth(t, v, args):
        return 1.5 * jnp.stack([jnp.cos(2 * t), jnp.sin(2 * t)]) - v / jnp.linalg.norm(v)

    t_eval = jnp.linspace(0.0, 4.0, 41)
    control = nj.PIDController(rtol=1e-5, atol=1e-7)
    kw = dict(stepper=nj.Trapezoidal(), controller=control, t_eval=t_eval)
    sol = scene.solve(0.0, 4.0, x0, args, **kw)
    ref = nj.solve(smooth, 0.0, 4.0, jnp.asarray([0.5, 0.3]), **kw)
    fine = solve_ivp(
        lambda t, v: np.asarray(smooth(t, v, None)),
        (0.0, 4.0),
        [0.5, 0.3],
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
        t_eval=np.asarray(t_eval),
    )
    xs, _ = scene.split(np.asarray(sol.y_eval))
    exact = fine.y.T
    error = np.max(np.abs(xs[:, 3:5] - exact))
    error_f = np.max(np.abs(np.asarray(ref.y_eval) - exact))
    assert sol.result == nj.RESULTS.successful
    assert int(sol.n_accepted) <= 1.2 * int(ref.n_accepted)
    assert error <= 1.5 * error_f


def test_cone_in_slip_starts_at_tight_tolerance():
    # A pushed block in slip at t0, rtol 1e-8: the start's first stage (velocities held)
    # leaves the reaction on a ray of solutions, its natural map at round-off (1e-12)
    # above the stage's tolerance (1e-13): Newton alternated between 4.5e-13 and 4e4
    # and the run failed at t0 with a nonlinear failure, for 4 of these 8 starts (every
    # stepper; rtol 1e-7 passed). The stages now converge at round-off; the reaction is
    # the physical one from the first step.
    scene, _, _ = nj.scenes.block_on_plane(cone=True, push=(1.5, 2.0))

    @jax.jit
    def run(x0, args):
        control = nj.PIDController(rtol=1e-8, atol=1e-10)
        kw = dict(stepper=nj.Trapezoidal(), controller=control, max_steps=512, throw=False)
        return scene.solve(0.0, 0.02, x0, args, **kw)

    for mu in (1 / G, 0.05):
        for v in ((0.5, 0.3), (0.3, 0.5), (1.0, 0.0), (0.2, -0.7)):
            _, x0, args = nj.scenes.block_on_plane(mu=mu, velocity=v, cone=True, push=(1.5, 2.0))
            sol = run(x0, args)
            assert sol.result == nj.RESULTS.successful, (mu, v, sol.result)
            k = int(sol.n_accepted)
            _, m = scene.split(np.asarray(sol.ys[: k + 1]))
            np.testing.assert_allclose(m["lam"][:, 0], G, rtol=1e-8)
            friction = -mu * G * np.asarray(v) / np.linalg.norm(v)
            np.testing.assert_allclose(m["lam"][0, 1:], friction, atol=1e-3)
