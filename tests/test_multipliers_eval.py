"""Multipliers at `t_eval` (issue 31, item 3; issue 24): a relay's selection in `y_eval`
against the forced relay's exact Filippov selection, a friction reaction and a box's
normal force in `Solution.multipliers_eval` against their closed forms, a resting
contact's force, and every output multiplier inside its set (float32 and float64)."""

import functools
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq

import nivpjax as nj
from benchmarks.sweeping_teval import AMPLITUDE, OMEGA, play_exact, sweeping_solve


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
from _references_switching import forced_relay_exact  # noqa: E402


# --- A forced relay: x' = -w + A sin(W t), w in sign(x), w on an algebraic row. ---------

A, W, X0 = 1.3, 2.0, 0.3
RELAY_PROJECTOR = nj.BlockProjector([([1], nj.Box(-1.0, 1.0))])
# Its sliding intervals (x = 0, w = A sin Wt) on [0, 2.4], from the exact solution: entered
# at 1.5989, left where |A sin Wt| = 1.
LEAVE = (np.pi + np.arcsin(1 / A)) / W  # A sin Wt = -1, 2.0096


def _relay_field(t, y, args):
    return jnp.stack([-y[1] + A * jnp.sin(W * t), y[0]])


@functools.cache
def _relay_program(name, adaptive):
    # One compiled program per stepper and step control; tolerances and steps are inputs.
    stepper = getattr(nj, name)()

    def run(t1, rtol, h0, t_eval):
        if adaptive:
            controller = nj.PIDController(rtol=rtol, atol=rtol / 100)
        else:
            controller = nj.ConstantStepSize()
        return nj.solve(
            _relay_field,
            0.0,
            t1,
            jnp.array([X0, 1.0]),
            projector=RELAY_PROJECTOR,
            mass_matrix=np.diag([1.0, 0.0]),
            stepper=stepper,
            controller=controller,
            h0=h0,
            t_eval=t_eval,
            max_steps=4000,
        )

    return jax.jit(run)


def _exact_selection(t, t1):
    x = forced_relay_exact(t, X0, A, W, t1)
    return np.where(x == 0.0, A * np.sin(W * t), np.sign(x)), x


def _transitions(t1):
    t = np.linspace(0.0, t1, int(t1 * 20000) + 1)
    sliding = forced_relay_exact(t, X0, A, W, t1) == 0.0
    return t[np.flatnonzero(np.diff(sliding.astype(int)))]


@pytest.mark.parametrize("name", ["Bathe"])
def test_relay_selection_at_teval_is_the_exact_selection(name):
    # Inside a sliding interval w is the equivalent control A sin Wt (Newton's step on the
    # hidden constraint at the interpolated state: exact for x' affine in w), outside it
    # is +-1 bit for bit. Before (linear between the steps' selections): Bathe 0.021 off
    # in sliding, 274 of 1601 outputs more than 1e-3 off (its selections at the steps are
    # its stages' values, not the phase's); the trapezoidal rule 2.5e-5 (h^2 u'' / 8).
    t1 = 8.0
    t_eval = np.linspace(0.0, t1, 1601)
    sol = _relay_program(name, True)(t1, 1e-5, None, jnp.asarray(t_eval))
    assert sol.result == nj.RESULTS.successful
    w = np.asarray(sol.y_eval[:, 1])
    exact, x = _exact_selection(t_eval, t1)
    assert np.all(np.abs(w) <= 1.0)
    # Away from the entries and exits (the steps locate them to the state's error).
    near = np.min(np.abs(t_eval[:, None] - _transitions(t1)[None, :]), axis=1) < 2e-3
    sliding = (x == 0.0) & ~near
    assert sliding.sum() > 400
    np.testing.assert_allclose(w[sliding], exact[sliding], rtol=0, atol=1e-9)
    off = (x != 0.0) & ~near
    assert np.array_equal(w[off], np.sign(x[off]))


@pytest.mark.parametrize("name", ["Trapezoidal", "Bathe", "BackwardEuler"])
def test_relay_selection_split_where_sliding_begins_or_ends_inside_a_step(name):
    # Fixed steps of 0.12: sliding is reached inside [1.56, 1.68] (at 1.5989 exactly) and
    # left inside [1.92, 2.04] (at 2.0096, where A sin Wt = -1). The selection stays the
    # start's (+1, x > 0) until the flow from the step's start reaches x = 0 and is the
    # equivalent control A sin Wt after; it is the equivalent control until that leaves
    # [-1, 1], and -1 after. A line between the steps' selections is O(1) off in both
    # steps (from 1 to the end's; from A sin Wt to -1).
    h, t1, start = 0.12, 2.4, 1.56
    t_eval = np.linspace(start, 2.04, 481)
    sol = _relay_program(name, False)(t1, 1.0, jnp.asarray(h), jnp.asarray(t_eval))
    ts = np.asarray(sol.ts[: int(sol.n_accepted) + 1])
    i = int(np.argmin(np.abs(ts - start)))
    assert abs(ts[i] - start) < 1e-9 and np.any(np.abs(ts - 2.04) < 1e-9)
    # The instant the exact flow from the step's own start (x0 off by the steps' error,
    # 3e-3 to 6e-3 here) reaches the surface: the interpolant's rule is judged, not the
    # steps'. The free flow to first order only would locate it 2e-3 late.
    x0 = float(sol.ys[i, 0])
    U = lambda t: -A / W * np.cos(W * t)  # noqa: E731
    reach = brentq(lambda t: x0 - (t - start) + U(t) - U(start), start, start + h)
    w = np.asarray(sol.y_eval[:, 1])
    expected = np.where(t_eval < reach, 1.0, np.where(t_eval < LEAVE, A * np.sin(W * t_eval), -1.0))
    assert np.all(np.abs(w) <= 1.0)
    far = (np.abs(t_eval - reach) > 2e-4) & (np.abs(t_eval - LEAVE) > 2e-4)
    np.testing.assert_allclose(w[far], expected[far], rtol=0, atol=1e-6)


# --- Friction: the spring slider's reaction, closed form. ------------------------------


def test_slider_friction_reaction_at_teval():
    # m = k = N = 1, mu = 0.6, v(0) = 0.1: in slip the reaction (per unit mass) is -0.6;
    # stuck from t* = atan(1/6) on, it holds the spring, -f = s(t*). The reaction the
    # interpolated state takes splits the step that ends in the stick where the state
    # stops. Before: only the steps' averages (Bathe's last slip step: -0.596, a line
    # through it 4e-3 off).
    scene, x0, args = nj.scenes.spring_slider()
    t_eval = np.linspace(0.0, 1.0, 201)
    t_star = np.arctan(1 / 6)
    s_star = -0.6 + 0.6 * np.cos(t_star) + 0.1 * np.sin(t_star)
    exact = np.where(t_eval < t_star, -0.6, s_star)
    for stepper in (nj.Trapezoidal(), nj.Bathe()):
        sol = scene.solve(
            0.0,
            1.0,
            x0,
            args,
            stepper=stepper,
            controller=nj.PIDController(rtol=1e-4, atol=1e-6),
            t_eval=jnp.asarray(t_eval),
        )
        r = np.asarray(sol.multipliers_eval[:, 1])
        assert sol.multipliers_eval.shape == sol.y_eval.shape
        assert np.all(np.abs(r) <= 0.6)
        np.testing.assert_allclose(r, exact, rtol=0, atol=1e-5)
        assert np.all(np.asarray(sol.multipliers_eval[:, 0]) == 0.0)  # no reaction on s


# --- A box on a differential row: the sweeping process's normal force. -----------------


def test_sweeping_normal_force_at_teval():
    # z' in -u' - N(z): at a face the reaction is -f = u'(t) (units of f), zero inside,
    # of the sign that pushes back into the box. The exact phase from the play operator.
    t_eval = np.linspace(0.0, 10.0, 2001)
    sol = sweeping_solve(nj.Bathe(), 1e-6, t_eval)
    z, r = np.asarray(sol.y_eval[:, 0]), np.asarray(sol.multipliers_eval[:, 0])
    # Feasible, bit for bit: zero inside, never pulling the state off the face it is on.
    assert np.all(r[np.abs(z) < 1.0] == 0.0)
    assert np.all(r[z == 1.0] <= 0.0) and np.all(r[z == -1.0] >= 0.0)
    exact_z = play_exact(t_eval)
    u_dot = AMPLITUDE * OMEGA * np.cos(OMEGA * t_eval)
    on_face = np.abs(np.abs(exact_z) - 1.0) < 1e-12
    held = on_face & (exact_z * u_dot < 0)  # the flow pushes out: the face holds it
    exact_r = np.where(held, u_dot, 0.0)
    # Away from arrivals and departures (located to the steps' error).
    clear = (np.abs(np.abs(exact_z) - 1.0) > 1e-2) | (held & (np.abs(u_dot) > 1e-2))
    assert clear.sum() > 1500 and held.sum() > 300
    np.testing.assert_allclose(r[clear], exact_r[clear], rtol=0, atol=1e-9)


# --- A resting contact's force. ----------------------------------------------------------


def test_ball_contact_force_at_teval():
    # The contact's force at an output time: zero in flight (the impacts are impulses,
    # applied at the steps' starts), and after the Zeno point (t = 1.91 for e = 0.5 from
    # H = 2) the resting force, g per unit mass on the velocity row, exactly (the
    # one-sided derivative of the contact's impulse at the interpolated state). Before:
    # the steps' residuals, -3.6e-15 in flight (Bathe), of either sign.
    scene, x0, args = nj.scenes.bouncing_ball(restitution=0.5, height=2.0)
    t_eval = np.linspace(0.0, 4.0, 801)
    sol = scene.solve(0.0, 4.0, x0, args, stepper=nj.Bathe(), t_eval=jnp.asarray(t_eval))
    assert sol.result == nj.RESULTS.successful
    height, force = np.asarray(sol.y_eval[:, 0]), np.asarray(sol.multipliers_eval[:, 1])
    flight = (t_eval < 1.85) & (height > 1e-6)
    assert flight.sum() > 300 and np.all(force[flight] == 0.0)
    assert np.all(force[t_eval > 2.0] == 9.81)
    assert np.all(force >= 0.0) and np.all(np.asarray(sol.multipliers_eval[:, 0]) == 0.0)


# --- Feasibility of every output multiplier, float32 and float64. ----------------------


def _projected_reactions(scene, args, sol):
    # The friction row of `Model.project_reaction` applied to the output reactions.
    from nivpjax._model import Model

    n = sol.y_eval.shape[1]
    model = Model.build(scene.vector_field, scene.projector, None, np.zeros(n, bool))
    project = jax.jit(jax.vmap(lambda t, y, r: model.project_reaction(t, y, r, args)))
    return np.asarray(project(sol.t_eval, sol.y_eval, sol.multipliers_eval)[:, 1])


def _stick_slip():
    return nj.scenes.spring_slider(
        mu_static=0.6, mu_kinetic=0.3, slip_scale=0.5, drive_velocity=0.2, velocity=0.0
    )


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_every_output_multiplier_inside_its_set(dtype):
    rtol = 1e-3 if dtype == jnp.float32 else 1e-6
    # Slip-weakening friction on a driven slider (stick-slip cycles): |r| <= mu(s) N / m
    # at the interpolated state, bit for bit.
    scene, x0, args = _stick_slip()
    args = jax.tree_util.tree_map(lambda a: jnp.asarray(a, dtype), args)
    t_eval = jnp.linspace(0.0, 20.0, 2001, dtype=dtype)
    sol = scene.solve(
        0.0,
        20.0,
        jnp.asarray(x0, dtype),
        args,
        controller=nj.PIDController(rtol=rtol, atol=rtol / 100),
        t_eval=t_eval,
    )
    assert sol.result == nj.RESULTS.successful and sol.multipliers_eval.dtype == dtype
    s, r = sol.y_eval[:, 0], sol.multipliers_eval[:, 1]
    mu = args["mu_k"] + (args["mu_s"] - args["mu_k"]) * jnp.exp(-jnp.abs(s) / args["Dc"])
    # The bound as evaluated here (the compiled program's own may differ by an ulp).
    bound = np.asarray(mu * args["N"] / args["m"])
    r = np.asarray(r)
    assert np.all(np.isfinite(r))
    assert np.all(np.abs(r) <= bound * (1 + 4 * float(jnp.finfo(dtype).eps)))
    slip, stick = np.abs(r) >= 0.999 * bound, np.abs(r) < 0.9 * bound
    assert slip.sum() > 100 and stick.sum() > 100
    # Inside the projector's own interval bit for bit: its Moreau projection leaves each
    # value as it is.
    model_args = (scene, args)
    assert np.array_equal(_projected_reactions(*model_args, sol), r)
    # The relay's selection: |w| <= 1 bit for bit.
    t_relay = jnp.linspace(0.0, 8.0, 1601, dtype=dtype)
    relay = nj.solve(
        lambda t, y, a: jnp.stack([-y[1] + A * jnp.sin(W * t), y[0]]).astype(dtype),
        0.0,
        8.0,
        jnp.array([X0, 1.0], dtype),
        projector=RELAY_PROJECTOR,
        mass_matrix=np.diag([1.0, 0.0]),
        controller=nj.PIDController(rtol=rtol, atol=rtol / 100),
        t_eval=t_relay,
        max_steps=4000,
    )
    assert relay.result == nj.RESULTS.successful
    w = np.asarray(relay.y_eval[:, 1])
    assert np.all(np.abs(w) <= 1.0) and np.any(np.abs(w) < 0.9)


def test_friction_reaction_put_into_its_bound_bit_for_bit():
    # In slip the law's reaction comes out of the projection's derivative as (F - c) - F,
    # which misses -c by the rounding of F - c (up to half an ulp of F): past the bound
    # for a large applied force F. `project_reaction` (Moreau's decomposition through the
    # projector, twice) puts every value inside [-c, c] bit for bit.
    from nivpjax._model import Model

    c = 0.3
    model = Model.build(
        lambda t, y, F: jnp.stack([y[1], F]),
        nj.BlockProjector([([1], nj.CoulombFriction(c))]),
        None,
        np.zeros(2, bool),
    )
    forces = jnp.asarray(np.geomspace(1.0, 1e6, 400)) * jnp.where(jnp.arange(400) % 2, 1, -1)
    y = jnp.array([0.0, 0.5])

    def both(F):
        f = model.f(0.0, y, F)
        raw = (
            model._moved_rate(jnp.asarray(0.0), jnp.asarray(1e-2), y, f, F, model.rated_rows)[0] - f
        )
        return raw[1], model.reaction_at(jnp.asarray(0.0), jnp.asarray(1e-2), y, F)[1]

    raw, r = map(np.asarray, jax.jit(jax.vmap(both))(forces))
    assert np.any(np.abs(raw) > c)  # the case exists: rounding past the bound
    assert np.all(np.abs(r) <= c)
    np.testing.assert_allclose(r, -c, rtol=1e-9)  # v > 0: the slip reaction -c


# --- The campaign's checks of the outputs. ------------------------------------------------


def test_campaign_output_checks_flag_values_outside_their_sets():
    # `outside_of_sets` reads 0 on a run whose outputs are all feasible, and flags a state
    # an ulp outside the box and a normal force of the wrong sign; `teval_ratio` meets the
    # issue's target on the sweeping family.
    from benchmarks import reliability as campaign
    from benchmarks.families import FAMILIES

    family = FAMILIES["sweeping"]
    params = family.grid[0]
    scene, run = campaign.compiled_run(family, "Bathe", "SSN", "default", outputs=True)
    _, x0, args = family.make(params)
    sol, outside = run(x0, args, 1e-4)
    assert sol.result == nj.RESULTS.successful and float(outside) == 0.0
    k = int(sol.n_accepted)
    ts, xs = np.asarray(sol.ts[: k + 1]), np.asarray(sol.ys[: k + 1])
    assert campaign.teval_ratio(family, params, scene, sol, ts, xs, 1e-4) <= 2.0

    check = jax.jit(lambda sol: campaign.outside_of_sets(scene, sol, args))
    z, r = sol.y_eval[:, 0], sol.multipliers_eval[:, 0]
    face = int(np.flatnonzero((np.abs(np.asarray(z)) == 1.0) & (np.asarray(r) != 0.0))[0])
    past = sol.y_eval.at[face, 0].set(np.nextafter(z[face], 2 * z[face]))
    wrong_sign = sol.multipliers_eval.at[face, 0].set(-r[face])
    assert float(check(sol)) == 0.0
    assert float(check(eqx_replace(sol, y_eval=past))) > 0.0
    assert float(check(eqx_replace(sol, multipliers_eval=wrong_sign))) > 0.0


def eqx_replace(sol, **fields):
    import equinox as eqx

    names = list(fields)
    return eqx.tree_at(lambda s: [getattr(s, n) for n in names], sol, [fields[n] for n in names])


def test_multipliers_at_teval_without_saved_steps():
    # `SaveAt(ts=...)` fills the states at the output times inside the loop; the
    # multipliers there are the same reactions (only the JVP's point, set by a step size,
    # differs: the last step's instead of each output's own).
    scene, x0, args = nj.scenes.spring_slider()
    t_eval = jnp.linspace(0.0, 1.0, 101)
    kwargs = dict(stepper=nj.Bathe(), controller=nj.PIDController(rtol=1e-4, atol=1e-6))
    saved = scene.solve(0.0, 1.0, x0, args, t_eval=t_eval, **kwargs)
    unsaved = scene.solve(0.0, 1.0, x0, args, saveat=nj.SaveAt(ts=t_eval), **kwargs)
    assert unsaved.ts is None
    # (The loop's program rounds differently: states agree to 1e-19 here.)
    np.testing.assert_allclose(np.asarray(unsaved.y_eval), np.asarray(saved.y_eval), atol=1e-15)
    np.testing.assert_allclose(
        np.asarray(unsaved.multipliers_eval), np.asarray(saved.multipliers_eval), atol=1e-12
    )
