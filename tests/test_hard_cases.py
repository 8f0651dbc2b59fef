"""Hard cases (issue 5): the situations nonsmooth integrators exist for, where smooth solvers
break. Each test asserts finite values throughout, constraint satisfaction within a stated
tolerance, bounded energy where the physics says so, and the reported result code.

Cases: resting contact and a zero-velocity impact (contact force = weight); Zeno accumulation
(e = 0.5, 0.8, 0.95); perfectly elastic bouncing (energy over 100 bounces); grazing contact
and a relay trajectory tangent to its switching surface; chattering-prone Filippov sliding
(first-order sliding-mode control); stick-slip under a slowly growing load; a contact problem
with a stiffness ratio of 1e8 integrated with steps of 22 fast periods; a stack of 10 balls,
also with a redundant (duplicated) floor contact; initial states violating a constraint
(penetration, a multiplier outside its set); float32 runs at loose tolerances (float64 ones
are checked to 1e-10 where the setting allows); hypothesis-generated variational
inequalities for both nonlinear solvers, including failures; a vmapped batch with one failing
member.

Cost (the file must stay within the CI budget): every configuration (scene, stepper, solver,
controller kind, dtype) is compiled once. Module-level `filter_jit` wrappers, cached per
configuration, take the initial state, the parameters, the horizon, the initial multipliers
and the controller (tolerances as arrays) or `h0` as traced inputs. Horizons and sizes are
small, and each scene runs a representative subset of the stepper x solver grid, stated next
to it: the four steppers (BackwardEuler, Trapezoidal, Bathe, EmbeddedBETR) with semismooth
Newton where the scene is cheap or the steppers differ, and the VI fixed-point method with
Bathe (with backward Euler on the stack). Bounds are 2-10x the values measured when the file
was written (stated inline); the round-off path of a nonsmooth run depends on how it is
compiled.

Library problems this suite found, each fixed and kept as a regression test: micro-bounces
after the Zeno point sustained by the VI solver's tolerance (Bathe + FixedPointVI; the VI
method now ends on its contracting projection step); the trapezoidal rule never settling a
ball whose gap is a round-off above zero (contacts are closed up to round-off); the
trapezoidal rule missing the breakaway of a stick under a slowly growing load (friction
reports a step that ends stuck above the static bound as a violation); an initial
penetration neither projected nor reported (now `initial_state_infeasible`);
`NonlinearSolution.value` outside its set when the solve did not converge (now projected).
"""

import functools
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra import numpy as hnp

import nivpjax as nj


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
from _references_mechanics import slider_event_driven  # noqa: E402


VI = nj.FixedPointVI()
STEPPERS = {
    "be": nj.BackwardEuler(),
    "tr": nj.Trapezoidal(),
    "bathe": nj.Bathe(),
    "betr": nj.EmbeddedBETR(),
    "be-vi": nj.BackwardEuler(solver=VI),
    "bathe-vi": nj.Bathe(solver=VI),
}
FIRST_ORDER = ("be", "betr")  # EmbeddedBETR propagates backward Euler
G = 9.81


def _f(x, dtype=jnp.float64):
    return jnp.asarray(x, dtype)


def _pid(rtol, atol, dtype=jnp.float64):
    # Tolerances as arrays: traced, so one executable serves every tolerance.
    return nj.PIDController(rtol=_f(rtol, dtype), atol=_f(atol, dtype))


@functools.cache
def _compiled(scene_name, stepper_name, adaptive, max_steps):
    """One executable per configuration; `x0`, `args`, `t1`, the controller (or `h0`) and the
    initial multipliers are traced."""
    scene = SCENES[scene_name]
    stepper = STEPPERS[stepper_name]

    @eqx.filter_jit
    def solve(x0, args, t1, control, multipliers=None):
        if adaptive:
            kwargs = dict(controller=control)
        else:
            kwargs = dict(controller=nj.ConstantStepSize(), h0=control)
        return scene.solve(
            jnp.zeros((), x0.dtype),
            t1,
            x0,
            args,
            stepper=stepper,
            max_steps=max_steps,
            throw=False,
            multipliers=multipliers,
            **kwargs,
        )

    return solve


def _run(scene_name, stepper_name, x0, args, t1, control, *, adaptive=True, max_steps, **kw):
    solve = _compiled(scene_name, stepper_name, adaptive, max_steps)
    dtype = jnp.asarray(x0).dtype
    sol = solve(jnp.asarray(x0), args, _f(t1, dtype), control, **kw)
    s = sol.trimmed()
    out = dict(
        sol=sol,
        ts=np.asarray(s.ts),
        ys=np.asarray(s.ys),
        hs=np.asarray(s.hs),
        mult=np.asarray(s.multipliers),
        attempts=int(sol.n_accepted) + int(sol.n_rejected),
    )
    assert np.all(np.isfinite(out["ys"])) and np.all(np.isfinite(out["mult"]))
    assert np.all(np.isfinite(np.asarray(sol.ys))) and np.all(np.isfinite(np.asarray(sol.y_final)))
    return out


def _code(sol):
    return nj.RESULTS[sol.result]


def _assert_ok(sol):
    assert sol.result == nj.RESULTS.successful, _code(sol)


# --------------------------------------------------------------------------------------------
# Scenes. Library scenes where they exist; three small ones built here with the public API.


def _lure_dynamics(t, x, a, m):
    u = a["amp"] * jnp.sin(2 * jnp.pi * a["freq"] * t) - a["k"] * m["w"][0]
    return a["A"] @ x + a["b"] * u


# x' = A x + b (d(t) - k w), w in sign(c.x), d(t) = amp sin(2 pi freq t): relay feedback of a
# linear plant in Lur'e form. One scene (one executable per stepper) covers the 1-D relay
# (A = 0, b = c = e1) and first-order sliding-mode control of a double integrator.
LURE = nj.Scene(_lure_dynamics, 2, (nj.Relay("w", lambda t, x, a: (a["c"] @ x)[None]),))


def _chain_dynamics(t, x, a, m):
    q1, q2, v1, v2 = x
    stretch = q2 - q1 - a["L"]
    f1 = -a["g"] - a["k1"] * (q1 - a["a"]) + a["k2"] * stretch
    return jnp.stack([v1, v2, f1, -a["g"] - a["k2"] * stretch])


# Two unit masses on the floor line: mass 1 (gap q1 >= 0, restitution e) hangs on a soft spring
# k1 around height a; mass 2 sits on mass 1 through a spring k2 of rest length L; gravity g.
# State (q1, q2, v1, v2). k2 = 0, g = 0: a harmonic impact oscillator (grazing); k2/k1 = 1e8:
# a stiff contact problem.
CHAIN = nj.Scene(
    _chain_dynamics,
    4,
    (
        nj.Contact(
            lambda t, x, a: x[:1],
            positions=[0],
            velocities=[2],
            restitution=lambda t, y, a: a["e"],
        ),
    ),
)


def _chain_energy(ys, a):
    q1, q2, v1, v2 = ys.T
    a = {k: float(v) for k, v in a.items()}
    return (
        0.5 * (v1**2 + v2**2)
        + 0.5 * a["k1"] * (q1 - a["a"]) ** 2
        + 0.5 * a["k2"] * (q2 - q1 - a["L"]) ** 2
        + a["g"] * (q1 + q2)
    )


N_STACK, R_STACK = 10, 0.5


def _stack_dynamics(t, x, a, m):
    return jnp.concatenate([x[N_STACK:], -a["g"] * jnp.ones(N_STACK, x.dtype)])


def _stack_gaps_redundant(t, x, a):
    q = x[:N_STACK]
    # The floor contact twice: a redundant contact set (singular Delassus matrix).
    return jnp.concatenate([q[:1] - R_STACK, q[:1] - R_STACK, q[1:] - q[:-1] - 2 * R_STACK])


STACK_REDUNDANT = nj.Scene(
    _stack_dynamics,
    2 * N_STACK,
    (
        nj.Contact(
            _stack_gaps_redundant,
            positions=np.arange(N_STACK),
            velocities=np.arange(N_STACK, 2 * N_STACK),
            restitution=lambda t, y, a: a["e"],
        ),
    ),
)

SCENES = {
    "ball": nj.scenes.bouncing_ball()[0],
    "slider": nj.scenes.spring_slider()[0],
    "stack": nj.scenes.ball_stack(n=N_STACK, radius=R_STACK)[0],
    "stack_redundant": STACK_REDUNDANT,
    "lure": LURE,
    "chain": CHAIN,
}


# --------------------------------------------------------------------------------------------
# Bouncing ball (adaptive, PID rtol 1e-4, atol 1e-6). Grid: the four steppers with Newton, and
# Bathe with the VI method (backward Euler + VI behaves as backward Euler + Newton here).

BALL_RTOL, BALL_ATOL = 1e-4, 1e-6
BALL_MAX = 30_000
BALL_GRID = ["be", "tr", "bathe", "betr", "bathe-vi"]


def _ball(name, x0, e, t1, rtol=BALL_RTOL, atol=BALL_ATOL, g=G):
    args = {"e": _f(e), "g": _f(g)}
    return _run("ball", name, _f(x0), args, t1, _pid(rtol, atol), max_steps=BALL_MAX)


def _t_inf(e, height=1.0, g=G):
    return np.sqrt(2 * height / g) * (1 + 2 * e / (1 - e))


def _penetration_bound(rtol, atol, speed):
    # A contact crossed inside a step counts as error scaled by atol + rtol |y0|_inf: the
    # accepted penetration is at most that (the documented event location), plus 10% for the
    # speed gained in the penetration itself.
    return 1.1 * (atol + rtol * speed)


@pytest.mark.parametrize("name", BALL_GRID)
def test_ball_resting_contact_carries_weight(name):
    # Released at height 0 with zero velocity (a zero-velocity impact): it stays exactly at
    # rest, and the velocity row of the multipliers (the reaction per unit time) is g.
    r = _ball(name, [0.0, 0.0], 0.8, 2.0)
    _assert_ok(r["sol"])
    assert np.all(r["ys"] == 0.0)
    np.testing.assert_allclose(r["mult"][1:, 1], G, rtol=1e-12)  # measured exact
    np.testing.assert_allclose(r["mult"][1:, 0], 0.0, atol=1e-12)
    assert r["attempts"] <= 20  # measured 8: steps grow x10 per step on a resting contact


def _zeno_params():
    return [
        pytest.param(name, e, id=f"{name}-e{e}") for name in BALL_GRID for e in (0.5, 0.8, 0.95)
    ]


@pytest.mark.parametrize("name, e", _zeno_params())
def test_ball_zeno_accumulation(name, e):
    t_inf = _t_inf(e)
    t1 = t_inf + 1.0
    r = _ball(name, [1.0, 0.0], e, t1)
    sol, ts, ys, hs = r["sol"], r["ts"], r["ys"], r["hs"]
    _assert_ok(sol)
    assert float(sol.t_final) == pytest.approx(t1, rel=1e-15)
    # Well inside max_steps: measured attempts (e = 0.5 / 0.8 / 0.95) be 858 / 2496 / 9013,
    # tr 304 / 1280 / 4688, bathe 261 / 1148 / 4981, betr 1061 / 3137 / 11438, bathe-vi
    # - / 1159 / 5040.
    assert r["attempts"] < BALL_MAX // 2
    # Never below the floor by more than the event tolerance.
    bound = _penetration_bound(BALL_RTOL, BALL_ATOL, np.sqrt(2 * G))
    assert ys[:, 0].min() >= -bound  # measured >= -2.5e-4 (bound 4.9e-4)
    # Energy height q + v^2/2g never exceeds the drop height: impacts only dissipate (to the
    # solver's tolerance: measured 2e-16 with Newton, 1.7e-8 with the VI method).
    energy = ys[:, 0] + ys[:, 1] ** 2 / (2 * G)
    assert energy.max() <= 1.0 + (1e-6 if name.endswith("-vi") else 1e-12)
    # At rest after the accumulation point: q at the floor, v = 0, reaction = weight.
    rest = (np.abs(ys[:, 1]) <= 1e-12) & (np.abs(ys[:, 0]) <= 1e-5)
    t_rest = ts[np.flatnonzero(~rest)[-1] + 1]
    if name in FIRST_ORDER:
        # Backward Euler damps free flight too: the bounces die out early (measured
        # t_inf - t_rest = 0.02 / 0.15 / 2.3 (be), 0.02 / 0.20 / 3.0 (betr) for e = 0.5 / 0.8
        # / 0.95, i.e. up to 17% of t_inf).
        assert 0.0 <= t_inf - t_rest <= 0.25 * t_inf
    else:
        # Event prediction lands a step on every impact, down to bounces at the contact's
        # round-off velocity sqrt(eps) (1 + |v|) = 1.5e-8 m/s, so rest comes at t_inf up to
        # the drift of the located impact times (each is applied at the end of a landing
        # step that stops up to 7e-8 m above the floor; measured drift of the impact times
        # against the exact ones up to 1.7e-6 s: bathe, e = 0.95, 325 impacts) plus the
        # step that settles it. Measured t_rest - t_inf for e = 0.5 / 0.8 / 0.95: tr 7e-8 /
        # 1.2e-7 / 3.4e-7, bathe 7e-9 / -1.1e-7 / 7.3e-7, bathe-vi 1.4e-8 / -1.0e-7 /
        # -7.9e-7 (before event prediction the last resolved bounce ended 6e-4 to 1.5e-2
        # before t_inf). Rest up to 1e-5 late is accepted: 6x the measured drift, and
        # below the timing error the controller accepts for a single impact (an impact
        # applied tau early is charged tau (1 + e) |v|, accepted up to atol + rtol |y|:
        # tau up to 5e-5 s at the first impact).
        assert -1e-5 <= t_inf - t_rest <= 0.05
    after = ts > t_inf + 0.05
    assert after.sum() >= 1 and np.all(rest[after])
    np.testing.assert_allclose(r["mult"][after, 1], G, rtol=1e-9)
    # The step size recovers once at rest (no sitting at h_min): measured >= 7.9e-2.
    assert hs[after].min() > 1e-3 and after.sum() <= 20


@pytest.mark.parametrize("name", ["be", "bathe", "tr"])
def test_ball_settles_at_tight_tolerance(name):
    # Dropped from 1e-13 with e = 0.95 (Zeno point 5.7e-6) at PID(1e-6, 1e-8): the ball must
    # come to rest at the floor (measured 87 attempts (be), 537 (bathe), 293 (tr); before
    # contacts closed up to round-off the trapezoidal rule spent all 30000 attempts
    # micro-bouncing on a gap of +1e-17).
    r = _ball(name, [1e-13, 0.0], 0.95, 1e-3, rtol=1e-6, atol=1e-8)
    _assert_ok(r["sol"])
    assert r["attempts"] < 3000
    # At rest on the floor: the gap is zero up to the contact's closure tolerance (16 eps)
    # and at most the event tolerance below it.
    eps = np.finfo(np.float64).eps
    assert -_penetration_bound(1e-6, 1e-8, 0.0) <= r["ys"][-1, 0] <= 16 * eps
    assert r["ys"][-1, 1] == 0.0


# Perfectly elastic bouncing: the trapezoidal rule and Bathe's scheme integrate free flight
# exactly (constant acceleration) and apply v+ = -v- at the located impact.
ELASTIC = {
    # Measured |E/E0 - 1| over 100 bounces: tr 1.6e-14, bathe 0.6e-5 to 1.4e-5, bathe-vi
    # 0.7e-5 to 1.1e-5 with steps shorter than a bounce (depending on how the solve is
    # compiled); 1e-15, 7e-15, 2e-15 since event prediction lands each step on an impact.
    "tr": 1e-12,
    "bathe": 1e-4,
    "bathe-vi": 1e-4,
}


def _elastic_ball_exact(ts, period):
    # Dropped from rest at height 1 with e = 1: the ball hits the floor at (k + 1/2) periods
    # and is back at the apex at whole periods. s = time from the nearest impact (signed).
    s = np.mod(ts, period) - period / 2
    flight = period / 2 - np.abs(s)
    return 1 - G / 2 * flight**2, np.sign(s) * G * flight, s


@pytest.mark.parametrize("name", list(ELASTIC))
def test_ball_elastic_energy_over_100_bounces(name):
    period = 2 * np.sqrt(2 / G)
    r = _ball(name, [1.0, 0.0], 1.0, 100 * period)
    _assert_ok(r["sol"])
    ts, ys = r["ts"], r["ys"]
    # 100 bounces, checked against the exact solution (impacts at (k + 1/2) periods, k = 0..99,
    # all inside the horizon) rather than by counting velocity jumps between output points:
    # that count describes the step sequence, not the motion (event prediction now lands
    # every step on the floor just before an impact and the next step applies it at its
    # start, so the outputs are one period apart, all at v = -sqrt(2g), and show no jump).
    # A missed or spurious bounce puts the ball a metre off the exact position.
    q_ex, v_ex, s = _elastic_ball_exact(ts, period)
    # Measured max |q - q_ex| 7.4e-6 (tr), 7.7e-6 (bathe), 7.4e-6 (bathe-vi): the impact
    # times drift by 1.7e-6 s over 100 impacts located to atol = 1e-6 (times the impact speed
    # 4.43: 7.4e-6 next to an impact).
    np.testing.assert_allclose(ys[:, 0], q_ex, rtol=0, atol=1e-4)
    # Velocities away from impacts (where the pre- and post-impact values differ by the
    # drift) and apexes: measured 7.3e-6 (tr), 1.2e-5 (bathe), 3.4e-6 (bathe-vi).
    away = (np.abs(s) > 1e-3) & (period / 2 - np.abs(s) > 1e-3)
    np.testing.assert_allclose(ys[away, 1], v_ex[away], rtol=0, atol=1e-4)
    # After the 100th bounce the ball is back at the apex: measured q = 1 - 1.4e-11,
    # v = -1.7e-5 (the drift of the impact times).
    np.testing.assert_allclose(ys[-1], [1.0, 0.0], rtol=0, atol=1e-4)
    energy = ys[:, 0] + ys[:, 1] ** 2 / (2 * G)
    assert np.max(np.abs(energy - 1.0)) < ELASTIC[name]
    bound = _penetration_bound(BALL_RTOL, BALL_ATOL, np.sqrt(2 * G))
    assert ys[:, 0].min() >= -bound  # measured >= -3.0e-7 (bound 4.9e-4)
    # Measured 114 (tr), 135 (bathe), 110 (bathe-vi): about one step per bounce (3959,
    # 3788, 3772 before event prediction).
    assert r["attempts"] < 1000


@pytest.mark.parametrize("name", ["be", "betr"])
def test_ball_elastic_dissipative_schemes(name):
    # Backward Euler damps free flight: with e = 1 the energy decreases (measured 0.942 (be),
    # 0.916 (betr) after 5 bounces) and never exceeds its initial value. (Not monotonically:
    # an impact activated by the lookahead moves the ball up by h v+ within its step,
    # measured +2.7e-4 at most.)
    period = 2 * np.sqrt(2 / G)
    r = _ball(name, [1.0, 0.0], 1.0, 5 * period)
    _assert_ok(r["sol"])
    energy = r["ys"][:, 0] + r["ys"][:, 1] ** 2 / (2 * G)
    assert energy.max() <= 1.0 + 1e-12
    assert 0.8 < energy[-1] < 0.99
    assert np.max(np.diff(energy)) < 1e-3


@pytest.mark.parametrize("v0", [0.0, -1.0], ids=["resting", "approaching"])
@pytest.mark.parametrize("name", ["be", "bathe"])
def test_ball_initial_penetration_reported(name, v0):
    # The ball starts 0.01 inside the floor. Velocity-level contact cannot push it out (at
    # rest it would stay inside with a successful run), so the documented behaviour is the
    # code `initial_state_infeasible` before any step, and with throw=True an error saying so.
    r = _ball(name, [-0.01, v0], 0.5, 1.0)
    sol = r["sol"]
    assert sol.result == nj.RESULTS.initial_state_infeasible, _code(sol)
    assert int(sol.n_accepted) == 0 and int(sol.n_rejected) == 0
    assert np.all(np.isfinite(r["ys"]))
    if name == "be" and v0 == 0.0:
        # Outside jit, throw=True raises before any step is taken (max_steps=1 suffices).
        scene = SCENES["ball"]
        x0, args = _f([-0.01, v0]), {"e": _f(0.5), "g": _f(G)}
        with pytest.raises(nj.SolveError, match="penetrated"):
            scene.solve(0.0, 1.0, x0, args, stepper=STEPPERS[name], max_steps=1, throw=True)


def test_ball_round_off_penetration_accepted():
    # A gap a round-off below zero (from computing positions) is not a violation: the ball
    # rests on the floor, the run succeeds.
    r = _ball("be", [-1e-12, 0.0], 0.5, 1.0)
    _assert_ok(r["sol"])
    assert np.all(np.abs(r["ys"][:, 0] + 1e-12) <= 1e-15)


# --------------------------------------------------------------------------------------------
# Relay and sliding-mode control (adaptive, PID rtol 1e-6, atol 1e-8). Grid: the four steppers
# with Newton, Bathe with the VI method.

LURE_GRID = ["be", "tr", "bathe", "betr", "bathe-vi"]
LURE_MAX = 8000


def _lure(name, x0, args, t1, w0=0.0):
    args = {k: _f(v) for k, v in args.items()}
    return _run(
        "lure",
        name,
        _f(x0),
        args,
        t1,
        _pid(1e-6, 1e-8),
        max_steps=LURE_MAX,
        multipliers={"w": _f(w0)},
    )


RELAY_1D = dict(A=np.zeros((2, 2)), b=[1.0, 0.0], c=[1.0, 0.0], k=1.0, amp=1.0, freq=1.0)
# x' = -w + sin(2 pi t) from x0 = 1/4 - 1/(2 pi): x' <= 0 and the free trajectory reaches
# x = 0 at t = 1/4 with x' = 0 (tangent to the switching surface), then slides with
# w = sin(2 pi t), whose |w| touches 1 at t = 1/4 + j/2 (the free vector field on one side is
# tangent to the surface again there). The exact x is 0 for t >= 1/4.
X0_TANGENT = 0.25 - 1 / (2 * np.pi)


def _relay_tangent_ref(ts):
    free = X0_TANGENT - ts + (1 - np.cos(2 * np.pi * ts)) / (2 * np.pi)
    return np.where(ts < 0.25, free, 0.0)


def _solver_tol(name):
    # The VI method stops at its tolerance (1e-8 relative, 1e-10 absolute); Newton overshoots.
    return 1e-8 if name.endswith("-vi") else 1e-12


@pytest.mark.parametrize("w0", [0.0, 5.0])
@pytest.mark.parametrize("name", LURE_GRID)
def test_relay_tangent_to_switching_surface(name, w0):
    r = _lure(name, [X0_TANGENT, 0.0], RELAY_1D, 2.0, w0=w0)
    _assert_ok(r["sol"])
    ts, ys = r["ts"], r["ys"]
    x, w = ys[:, 0], ys[:, 2]
    # w0 = 5 lies outside [-1, 1]: the consistent multiplier at t0 is sign(x0) = 1.
    assert w[0] == 1.0
    tol = _solver_tol(name)
    # Never crosses to the other side; measured |x - ref| 4.8e-5 (be), 6.8e-5 (betr), 1.8e-6
    # (tr), 1.4e-6 (bathe): the tangential approach x ~ (1/4 - t)^3 is slow to resolve.
    assert x.min() >= -100 * tol
    np.testing.assert_allclose(x, _relay_tangent_ref(ts), rtol=0, atol=2e-4)
    # On the surface after the touch, including at the tangencies t = 0.75, 1.25, 1.75.
    after = ts > 0.3
    assert np.max(np.abs(x[after])) <= 100 * tol
    # The selection stays in sign's convex hull and equals the equivalent control sin(2 pi t)
    # (measured 1e-16 with Newton, 2.4e-9 with the VI method; the trapezoidal multiplier
    # rings after the switch, as documented: measured 6e-4).
    assert np.all(np.abs(w) <= 1.0)
    d = np.sin(2 * np.pi * ts)
    ring = 1e-2 if name.startswith("tr") else 1e-6
    np.testing.assert_allclose(w[after], d[after], rtol=0, atol=ring)


SMC = dict(A=[[0.0, 1.0], [0.0, 0.0]], b=[0.0, 1.0], c=[1.0, 1.0], k=2.0, amp=0.5, freq=1.0)
# x1' = x2, x2' = d(t) - 2 w, w in sign(x1 + x2): reaching in finite time, then sliding on
# s = x1 + x2 = 0 with x1 ~ exp(-t) and the equivalent control w = (d + x2)/2 in (-1, 1).
# An explicit scheme chatters around s = 0; an implicit one must not.


@pytest.mark.parametrize("name", LURE_GRID)
def test_sliding_mode_control_without_chattering(name):
    r = _lure(name, [1.0, 0.0], SMC, 3.0)
    sol, ts, ys, hs = r["sol"], r["ts"], r["ys"], r["hs"]
    _assert_ok(sol)
    x1, x2, w = ys[:, 0], ys[:, 1], ys[:, 2]
    s = x1 + x2
    k = np.flatnonzero(np.abs(s) <= 1e-9)[0]
    t_reach = ts[k]
    assert 0.45 < t_reach < 0.52  # measured 0.482-0.484
    sliding = np.arange(ts.size) > k
    tol = _solver_tol(name)
    assert np.max(np.abs(s[sliding])) <= 100 * tol  # measured 0 (Newton), 3.4e-11 (VI)
    assert np.all(np.abs(w) <= 1.0)
    d = 0.5 * np.sin(2 * np.pi * ts)
    if not name.startswith("tr"):  # the trapezoidal multiplier rings (documented)
        # Measured 2.7e-13 (Newton); VI 5.2e-8, and 2.3e-6 at one step of another step
        # sequence: the VI method stops on the residual, where a multiplier error in sliding
        # shows only through the state it moves, h^2 k times smaller.
        atol = 1e-5 if name.endswith("-vi") else 1e-10
        np.testing.assert_allclose(w[sliding], (d + x2)[sliding] / 2, rtol=0, atol=atol)
    # Exponential decay along the surface; measured 1.3e-4 (be), 1.9e-4 (betr), 6e-6 (tr,
    # bathe).
    decay = x1[k] * np.exp(-(ts[sliding] - t_reach))
    np.testing.assert_allclose(x1[sliding], decay, rtol=0, atol=2e-3)
    # Step sizes in sliding (after a 3-step transition, before the last step, which lands on
    # t1) follow the smooth motion: consecutive steps within 10% of each other (measured
    # within 0.3%), and few rejections (measured 0 (be), 6 (bathe), 1 (betr), 5 (bathe-vi)).
    # The trapezoidal rule's ringing multiplier feeds its Richardson estimate: its steps
    # jump by factors 0.2-10 in sliding (29 rejections), bounded but not smooth.
    steady = hs[k + 4 : -1]
    ratio = steady[1:] / steady[:-1]
    smooth = np.all((0.9 <= ratio) & (ratio <= 1.1)) and int(sol.n_rejected) <= 10
    if name.startswith("tr"):
        assert np.all((0.1 <= ratio) & (ratio <= 10.0)) and int(sol.n_rejected) <= 60
    elif name == "bathe-vi" and not smooth:
        # Known, open: the VI method's inexact multipliers (s ~ 1e-12, w off by ~1e-8) feed
        # Bathe's embedded estimate, and its sliding steps are irregular (measured ~250
        # ratios outside [0.9, 1.1], ~270 rejections; unchanged without event prediction).
        # Everything above (on the surface, w = w_eq, the decay) holds.
        pytest.xfail("Bathe + VI: irregular steps in sliding (embedded estimate, VI noise)")
    else:
        assert smooth


# --------------------------------------------------------------------------------------------
# Stick-slip (adaptive, PID rtol 1e-4, atol 1e-6). Grid: EmbeddedBETR (backward Euler
# propagated), Bathe and the trapezoidal rule with Newton, Bathe with the VI method (backward
# Euler with either solver behaves as EmbeddedBETR here: measured breakaway and switch times
# within 0.02 of each other).

SLIDER_GRID = ["betr", "bathe", "bathe-vi", "tr"]
SLOW = dict(mu_static=0.6, mu_kinetic=0.3, slip_scale=0.5, drive_velocity=0.01, velocity=0.0)
T_SLIDER = 75.0


@functools.cache
def _slider_reference():
    _, x0, args = nj.scenes.spring_slider(**SLOW)
    p = {k: float(v) for k, v in args.items()}
    t = np.linspace(0.0, T_SLIDER, 7501)
    s, v, switches = slider_event_driven(p, 0.0, 0.0, T_SLIDER, t)
    return x0, args, p, switches


@pytest.mark.parametrize("name", SLIDER_GRID)
def test_stick_slip_under_slowly_growing_load(name):
    # A spring pulled at V = 0.01 loads a block held by static friction mu_s = 0.6, which
    # weakens to mu_k = 0.3 once it slips (Dc = 0.5): stick until k V t = mu_s N (t = 60), then
    # a slip, a second stick and a second slip before t = 75.
    x0, args, p, switches = _slider_reference()
    assert [m for _, m in switches] == [0, 1, 0, 1]
    t_break = switches[1][0]
    assert abs(t_break - 60.0) < 1e-9
    r = _run("slider", name, x0, args, T_SLIDER, _pid(1e-4, 1e-6), max_steps=4000)
    _assert_ok(r["sol"])
    ts, ys, mult = r["ts"], r["ys"], r["mult"]
    s, v = ys[:, 0], ys[:, 1]
    stuck = np.abs(v) <= 1e-12
    spring = p["k"] * (p["V"] * ts - s)
    mu = p["mu_k"] + (p["mu_s"] - p["mu_k"]) * np.exp(-np.abs(s) / p["Dc"])
    # Sticking under the growing load: exactly at rest until the breakaway step.
    assert not np.all(stuck), "the block never slips"
    k = np.flatnonzero(~stuck)[0]
    assert np.max(np.abs(s[:k])) <= 1e-12  # measured 3e-15 (round-off)
    # The block cannot move before the load reaches the static bound; the breakaway is
    # located within 0.2 (measured: the last stuck state at 59.91-59.99). The trapezoidal
    # rule and Bathe's scheme see it through CoulombFriction.violation: a step that ends
    # stuck with the load above the bound is rejected (before that check the trapezoidal
    # rule stepped 11 -> 75 in stick and never slipped).
    assert ts[k] >= t_break - 1e-9 and ts[k - 1] >= t_break - 0.2
    # In every stick the friction force (velocity row of the multipliers) balances the
    # spring within the static bound (row 0 has no stage).
    inner = stuck & np.roll(stuck, 1) & (ts > 0)
    if name == "tr":
        # A trapezoidal stage balances the average of the loads at its two ends (the step
        # is one stage: its estimate is embedded, no Richardson half steps any more).
        balanced = 0.5 * spring + 0.5 * np.roll(spring, 1)
    else:
        balanced = spring
    np.testing.assert_allclose(mult[inner, 1], -balanced[inner], rtol=0, atol=1e-9)
    # Within the static bound up to what the error test accepts: a step of size h that
    # ends stuck with the load above the bound counts h times the excess as error (the
    # velocity the block would gain), accepted up to atol + rtol |y0| (measured: no excess
    # for most schemes; 1.8e-5 for the trapezoidal rule's step of 0.016 across the
    # breakaway at t = 60, against a slack of 6.2e-5).
    h = np.diff(ts, prepend=ts[0])
    scale = 1e-6 + 1e-4 * np.max(np.abs(np.roll(ys[:, :2], 1, axis=0)), axis=1)
    slack = scale / np.where(h > 0, h, 1.0)
    assert np.all(np.abs(spring[inner]) <= mu[inner] * p["N"] + slack[inner] + 1e-9)
    # Slip-stick-slip as the event-driven reference: each reference switch within 0.15 of the
    # step where the numerical solution switches (measured 0.05 at most). The trapezoidal
    # rule at this loose rtol (1e-4) with its embedded estimate puts the second stick 0.18
    # early: the weakening slip amplifies its step errors (with Richardson it was 0.05), so
    # it gets 0.25.
    change = np.flatnonzero(stuck[1:] != stuck[:-1])
    assert change.size == len(switches) - 1
    slack = 0.25 if name == "tr" else 0.15
    for i, (t_switch, _) in zip(change, switches[1:]):
        assert ts[i] - slack <= t_switch <= ts[i + 1] + slack
    assert r["attempts"] < 2000  # measured 700 (betr), 147 (bathe), 146 (bathe-vi), 237 (tr)


# --------------------------------------------------------------------------------------------
# Impact oscillator (fixed steps): grazing contact and a stiffness ratio of 1e8. Grid: the four
# steppers with Newton, Bathe with the VI method.

CHAIN_GRID = ["be", "tr", "bathe", "betr", "bathe-vi"]
CHAIN_MAX = 2500


def _chain(name, x0, t1, h, **args):
    args = {k: _f(v) for k, v in args.items()}
    return _run("chain", name, _f(x0), args, t1, _f(h), adaptive=False, max_steps=CHAIN_MAX), args


GRAZING = dict(g=0.0, k1=1.0, a=1.0, k2=0.0, L=1.0)


@pytest.mark.parametrize("name", CHAIN_GRID)
def test_grazing_contact(name):
    # q1'' = -(q1 - 1) from q1 = 2 at rest: q1 = 1 + cos t touches the floor at t = pi with
    # zero velocity and zero force and leaves again (grazing). The contact must stay
    # inactive: no impulse, so the restitution coefficient changes nothing.
    runs = {e: _chain(name, [2.0, 3.0, 0.0, 0.0], 3 * np.pi, 0.01, e=e, **GRAZING) for e in (0, 1)}
    (r0, args), (r1, _) = runs[0], runs[1]
    for r in (r0, r1):
        _assert_ok(r["sol"])
    np.testing.assert_array_equal(r0["ys"], r1["ys"])
    ts, ys, mult = r0["ts"], r0["ys"], r0["mult"]
    assert ys[:, 0].min() >= -1e-12  # measured >= 3e-9 (tr), 1.3e-6 (bathe), 1.6e-2 (be)
    # Float64 tight: no reaction on the contact row, the stage residual of the free motion
    # (measured 3e-14 with Newton; the VI method stops at rtol |y| / h = 2e-6 on this row,
    # measured 5.6e-8).
    assert np.max(np.abs(mult[1:, 2])) <= (2e-6 if name.endswith("-vi") else 1e-10)
    energy = _chain_energy(ys, args)
    assert np.all(energy <= energy[0] * (1 + 1e-12))  # no scheme gains energy
    if name.startswith("tr"):
        # The trapezoidal rule conserves the quadratic energy of a linear system exactly.
        np.testing.assert_allclose(energy, energy[0], rtol=1e-10)  # measured 2.6e-15
    if name.startswith(("tr", "bathe")):
        # Second order: measured 6.6e-5 (tr), 3.7e-5 (bathe) at h = 0.01.
        np.testing.assert_allclose(ys[:, 0], 1 + np.cos(ts), rtol=0, atol=5e-4)


STIFF = dict(g=G, k1=1.0, a=0.0, k2=1e8, L=1.0, e=0.0)


@pytest.mark.parametrize("name", ["be", "bathe", "betr", "bathe-vi"])
def test_stiff_contact_large_steps(name):
    # Stiffness ratio k2/k1 = 1e8: the fast mode has period 2 pi / sqrt(2 k2) = 4.4e-4; h = 0.01
    # is 22 periods (h sqrt(k2) = 100). Dropped from 0.5 with the stiff spring stretched by 1e-3
    # (fast-mode energy 50): L-stable schemes damp it at once and the pair lands and rests.
    h = 0.01
    r, args = _chain(name, [0.5, 1.501, 0.0, 0.0], 2.0, h, **STIFF)
    _assert_ok(r["sol"])
    ys, mult = r["ys"], r["mult"]
    assert np.max(np.abs(ys)) < 10  # measured 3.2
    energy = _chain_energy(ys, args)
    assert np.all(energy <= energy[0] * (1 + 1e-12))  # measured: decreasing
    # Landing at 3.1 m/s with steps of 0.01: a velocity-level impact leaves an O(h |u|) overlap.
    assert ys[:, 0].min() >= -h * np.sqrt(2 * G * 0.5)  # measured >= -2e-3
    # At rest: static stretch -g/k2 of the stiff spring, contact force = weight of both
    # masses minus the soft spring's pull, 2g + k1 q1 (reaction per unit time on v1).
    final = ys[-1]
    assert np.max(np.abs(final[2:])) <= 1e-8  # measured <= 2.6e-11
    np.testing.assert_allclose(final[1] - final[0] - 1.0, -G / 1e8, rtol=1e-6)
    np.testing.assert_allclose(mult[-1, 2], 2 * G + final[0], rtol=1e-9)  # measured 6e-11


def test_stiff_contact_trapezoidal_stays_bounded():
    # A-stable but not L-stable: the fast mode is not damped (|R(inf)| = 1) and the contact,
    # closed while the bottom mass rings, feeds it: measured energy +33% (69.8 -> 93.1 max) at
    # h = 0.01. No blow-up, though.
    r, args = _chain("tr", [0.5, 1.501, 0.0, 0.0], 2.0, 0.01, **STIFF)
    _assert_ok(r["sol"])
    assert np.max(np.abs(r["ys"])) < 100  # measured 12
    energy = _chain_energy(r["ys"], args)
    assert energy.max() < 2 * energy[0]


# --------------------------------------------------------------------------------------------
# A stack of 10 balls (fixed steps h = 0.01): 10 simultaneous contacts, and an 11th duplicating
# the floor contact (a redundant set: the Delassus matrix is singular). Grid: backward Euler
# with both solvers, and with Newton on the redundant set (Bathe behaves the same here).

STACK_GRID = [("stack", "be"), ("stack", "be-vi"), ("stack_redundant", "be")]
STACK_CASES = {
    # case: (initial state, horizon)
    "rest": (nj.scenes.ball_stack(n=N_STACK, radius=R_STACK)[1], 1.0),
    "drop": (nj.scenes.ball_stack(n=N_STACK, radius=R_STACK, spacing=0.1)[1], 1.5),
    # The top ball 0.5 above the resting column, falling at 2 m/s: impacts through the column.
    "hit": (
        jnp.asarray(nj.scenes.ball_stack(n=N_STACK, radius=R_STACK)[1])
        .at[N_STACK - 1]
        .add(0.5)
        .at[2 * N_STACK - 1]
        .set(-2.0),
        1.0,
    ),
}


@pytest.mark.parametrize("case", list(STACK_CASES))
@pytest.mark.parametrize("scene, name", STACK_GRID, ids=[f"{s}-{n}" for s, n in STACK_GRID])
def test_ball_stack(scene, name, case):
    x0, t1 = STACK_CASES[case]
    h = 0.01
    args = {"e": _f(0.0), "g": _f(G)}
    r = _run(scene, name, x0, args, t1, _f(h), adaptive=False, max_steps=200)
    _assert_ok(r["sol"])
    ys, mult = r["ys"], r["mult"]
    q, v = ys[:, :N_STACK], ys[:, N_STACK:]
    gaps = np.concatenate([q[:, :1] - R_STACK, np.diff(q, axis=1) - 2 * R_STACK], axis=1)
    redundant = scene == "stack_redundant"
    # The redundant set falls back to projected Gauss-Seidel (500 sweeps), which leaves a
    # velocity residual: the column sinks at ~1e-7 m/s (measured), force error 1.4e-5.
    v_tol, f_tol = (1e-6, 1e-4) if redundant else (1e-12, 1e-9)
    # Overlaps: O(h |u|) at an impact with fixed steps (|u| <= sqrt(2 g 0.9) = 4.2).
    assert gaps.min() >= -h * 4.2 / 2 - 1e-6  # measured -2.1e-2 (be drop)
    assert np.all(gaps[-1] <= 1e-12)  # all in contact at the end
    assert np.max(np.abs(v[-1])) <= v_tol
    # At rest every ball's net contact force balances its weight (per unit mass).
    np.testing.assert_allclose(mult[-1, N_STACK:], G, rtol=0, atol=f_tol * G)
    # Inelastic contacts: the energy never grows.
    energy = np.sum(0.5 * v**2 + G * q, axis=1)
    assert np.all(energy <= energy[0] + 1e-9)  # measured increments <= 1.7e-13
    if case == "rest":
        assert np.max(np.abs(ys - np.asarray(x0))) <= (1e-6 if redundant else 1e-14)


# --------------------------------------------------------------------------------------------
# float32 at loose tolerances (rtol = atol = 1e-3). Tighter atol in float32 fails with
# h_min_reached at slow impacts: the Richardson estimate of an impact step is g h / 2 in
# velocity, so acceptance needs h <= 2 atol / g, below float32's default h_min ~ 64 eps |t|.

F32 = jnp.float32


@pytest.mark.parametrize("e", [0.5, 0.8])
def test_float32_ball_zeno(e):
    args = {"e": _f(e, F32), "g": _f(G, F32)}
    t_inf = _t_inf(e)
    r = _run(
        "ball",
        "betr",
        _f([1.0, 0.0], F32),
        args,
        t_inf + 1.0,
        _pid(1e-3, 1e-3, F32),
        max_steps=3000,
    )
    sol, ts, ys = r["sol"], r["ts"], r["ys"]
    _assert_ok(sol)
    assert ys.dtype == np.float32 and r["attempts"] < 1500  # measured 109 / 260
    assert ys[:, 0].min() >= -5e-3  # measured -1.3e-3 / -2.0e-3 (1e-3 + 1e-3 * 4.4)
    after = ts > t_inf + 0.05
    assert np.all(np.abs(ys[after, 1]) == 0.0) and np.all(np.abs(ys[after, 0]) < 2e-3)
    np.testing.assert_allclose(r["mult"][-1, 1], G, rtol=1e-5)


def test_float32_sliding_mode_control():
    args = {k: _f(v, F32) for k, v in SMC.items()}
    r = _run(
        "lure",
        "betr",
        _f([1.0, 0.0], F32),
        args,
        3.0,
        _pid(1e-3, 1e-3, F32),
        max_steps=2000,
        multipliers={"w": _f(0.0, F32)},
    )
    _assert_ok(r["sol"])
    ts, ys = r["ts"], r["ys"]
    s = ys[:, 0] + ys[:, 1]
    k = np.flatnonzero(np.abs(s) <= 1e-6)[0]
    assert 0.4 < ts[k] < 0.6
    assert np.max(np.abs(s[k + 1 :])) <= 1e-6
    assert np.all(np.abs(ys[:, 2]) <= 1.0)
    d = 0.5 * np.sin(2 * np.pi * ts)
    # Measured: reaching at 0.491, |s| <= 6e-8 after it, |w - w_eq| <= 3e-7.
    np.testing.assert_allclose(ys[k + 1 :, 2], (d + ys[:, 1])[k + 1 :] / 2, rtol=0, atol=3e-6)


def test_float32_grazing_trapezoidal():
    args = {k: _f(v, F32) for k, v in dict(GRAZING, e=0.5).items()}
    r = _run(
        "chain",
        "tr",
        _f([2.0, 3.0, 0.0, 0.0], F32),
        args,
        3 * np.pi,
        _f(0.01, F32),
        adaptive=False,
        max_steps=CHAIN_MAX,
    )
    _assert_ok(r["sol"])
    ys = r["ys"]
    assert ys.dtype == np.float32
    assert ys[:, 0].min() >= -1e-5  # measured >= 1.3e-6
    energy = _chain_energy(ys.astype(np.float64), args)
    np.testing.assert_allclose(energy, energy[0], rtol=1e-5)  # measured 3.1e-6
    np.testing.assert_allclose(ys[:, 0], 1 + np.cos(r["ts"]), rtol=0, atol=1e-3)  # 1.5e-4


# --------------------------------------------------------------------------------------------
# vmap: one failing member of a batch (a step size too small for max_steps) does not corrupt
# the others, and each member reports its own result.


VMAP_MAX = 400


@functools.cache
def _chain_batched():
    scene = SCENES["chain"]

    @eqx.filter_jit
    def solve(x0, args, h0):
        return jax.vmap(
            lambda x0, args, h0: scene.solve(
                0.0,
                2.0,
                x0,
                args,
                stepper=STEPPERS["be"],
                controller=nj.ConstantStepSize(),
                h0=h0,
                max_steps=VMAP_MAX,
                throw=False,
            )
        )(x0, args, h0)

    return solve


def test_vmap_failure_is_per_member():
    # Three members (backward Euler, fixed steps): the stiff drop with h = 0.01, the same with
    # h = 1e-4 (needs 20000 steps: max_steps 400 is reached), and the grazing oscillator.
    x0 = np.array([[0.5, 1.501, 0.0, 0.0]] * 2 + [[2.0, 3.0, 0.0, 0.0]])
    members = [STIFF, STIFF, dict(GRAZING, e=0.0)]
    args = {k: _f([m[k] for m in members]) for k in STIFF}
    h0 = _f([0.01, 1e-4, 0.01])
    sol = _chain_batched()(_f(x0), args, h0)
    codes = np.asarray(sol.result._value)
    assert codes[0] == codes[2] == nj.RESULTS.successful._value
    assert codes[1] == nj.RESULTS.time_max_steps_reached._value
    assert np.all(np.isfinite(np.asarray(sol.ys))) and np.all(np.isfinite(np.asarray(sol.y_final)))
    np.testing.assert_allclose(np.asarray(sol.t_final), [2.0, VMAP_MAX * 1e-4, 2.0], rtol=1e-9)
    # The other members equal their unbatched runs (same executable family, batched).
    for i in (0, 2):
        r, _ = _chain("be", x0[i], 2.0, float(h0[i]), **members[i])
        n = int(sol.n_accepted[i])
        assert n == int(r["sol"].n_accepted) == 200
        np.testing.assert_allclose(np.asarray(sol.ys[i, : n + 1]), r["ys"], rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.asarray(sol.multipliers[i, : n + 1]), r["mult"], atol=1e-9)


# --------------------------------------------------------------------------------------------
# Random small variational inequalities: find y in K with <R(y), x - y> >= 0 for all x in K,
# R(y) = M y + q, M = B B^T + mu I positive definite, K = Box x NonNegative x Ball (blocks of
# 2). Both solvers, compiled once each (the data are traced).

N_VI = 6


def _vi_projector(lo, hi, radius):
    return nj.BlockProjector(
        [
            ((0, 1), nj.Box(lo, hi)),
            ((2, 3), nj.NonNegative()),
            ((4, 5), nj.Ball(radius)),
        ]
    )


def _vi_project_point(x, lo, hi, radius):
    return _vi_projector(lo, hi, radius)(x, nj.default_context(x))


@functools.cache
def _vi_solve(solver):
    @eqx.filter_jit
    def solve(M, q, lo, hi, radius, y0):
        projector = _vi_projector(lo, hi, radius)

        def project(z, y, rho):
            ctx = nj.ProjectionContext(
                t=jnp.zeros(()), h=jnp.ones(()), y_prev=y, y_iter=y, rho=rho, args=None
            )
            return projector(z, ctx)

        return solver.solve(lambda y: M @ y + q, project, jnp.ones(N_VI), y0)

    return solve


VI_SOLVERS = {
    "newton": nj.SemismoothNewton(),
    "vi": nj.FixedPointVI(),
    # Budgets too small to converge: the failure must be reported as such.
    "newton_1": nj.SemismoothNewton(rtol=1e-14, atol=1e-14, max_steps=1),
    "vi_2": nj.FixedPointVI(rtol=1e-14, atol=1e-14, max_steps=2),
}


@st.composite
def vi_problems(draw):
    scale = 10.0 ** draw(st.integers(-3, 3))
    el = st.floats(-2, 2, allow_nan=False, allow_infinity=False, allow_subnormal=False)
    B = draw(hnp.arrays(np.float64, (N_VI, N_VI), elements=el))
    mu = draw(st.floats(0.05, 2.0))
    M = (B @ B.T + mu * np.eye(N_VI)) / (1 + np.linalg.norm(B) ** 2 / N_VI)
    q = scale * draw(hnp.arrays(np.float64, (N_VI,), elements=el))
    lo = draw(hnp.arrays(np.float64, (2,), elements=st.floats(-2, 0)))
    width = draw(hnp.arrays(np.float64, (2,), elements=st.floats(0, 2)))  # 0: lo == hi
    radius = draw(st.floats(0, 2))  # 0: the ball is a point
    y0 = draw(hnp.arrays(np.float64, (N_VI,), elements=el))
    samples = draw(hnp.arrays(np.float64, (8, N_VI), elements=st.floats(-5, 5)))
    return M, q, lo, lo + width, radius, y0, samples


def _vi_args(problem):
    M, q, lo, hi, radius, y0, _ = problem
    return tuple(jnp.asarray(a) for a in (M, q, lo, hi, radius, y0))


@pytest.mark.parametrize("name", list(VI_SOLVERS))
@settings(max_examples=25, deadline=None)
@given(problem=vi_problems())
def test_random_vi(name, problem):
    M, q, lo, hi, radius, y0, samples = problem
    solver = VI_SOLVERS[name]
    sol = _vi_solve(solver)(*_vi_args(problem))
    y = np.asarray(sol.value)
    res = float(sol.residual_norm)
    # Never NaN for finite input, converged or not.
    assert np.all(np.isfinite(y)) and np.isfinite(res)
    assert np.all(np.isfinite(np.asarray(sol.history[: int(sol.iterations) + 1])[1:]))
    # The code matches the residual: successful iff |G| meets the tolerance (clamped to 8 eps),
    # otherwise nonlinear_max_steps_reached.
    atol = max(solver.atol, 8 * np.finfo(np.float64).eps)
    rtol = max(solver.rtol, 8 * np.finfo(np.float64).eps)
    if sol.result != nj.RESULTS.successful:
        assert sol.result == nj.RESULTS.nonlinear_max_steps_reached, _code(sol)
        assert res > atol
        assert 1 <= int(sol.iterations) <= solver.max_steps
        # Semismooth Newton converges on these strongly monotone, piecewise-smooth problems
        # (measured <= 6 iterations); the projection method converges linearly, at a rate
        # 1 - O(1/cond(M)), and may need more than its 500 steps (cond(M) ~ 70 does).
        assert name != "newton"
        return
    assert res <= atol + rtol * (np.abs(y).max() + res)
    # y lies in K to the tolerance (components the projector moves are returned projected,
    # the others keep the iterate, within |G| of the set; see test_vi_value_in_set_when_not
    # _converged for the unconverged case).
    tol = atol + rtol * np.abs(y).max()
    assert np.all((lo - tol <= y[:2]) & (y[:2] <= hi + tol)) and np.all(y[2:4] >= -tol)
    assert np.linalg.norm(y[4:]) <= radius + 2 * tol
    # The variational inequality at sampled feasible points, to the solver's tolerance:
    # <R(y), x - y> >= -|G(y)| (|x - y| + |R(y)|) up to the projection's round-off.
    R = M @ y + q
    eps = res * np.sqrt(N_VI)
    # R is known to its round-off, ~ n eps (|M| |y| + |q|), e.g. 2.8e-14 at y ~ 933.
    unit = np.finfo(np.float64).eps
    roundoff = (
        8
        * N_VI
        * unit
        * (np.linalg.norm(M) * np.linalg.norm(y) + np.linalg.norm(q) + np.linalg.norm(R) + 1)
    )
    for x in samples:
        x = np.asarray(_vi_project_point(jnp.asarray(x), lo, hi, radius))
        slack = eps * (np.linalg.norm(x - y) + np.linalg.norm(R)) * (1 + np.linalg.norm(M))
        assert R @ (x - y) >= -(slack + roundoff * (1 + np.linalg.norm(x - y)))


def test_vi_value_in_set_when_not_converged():
    # A failing example of test_random_vi[newton_1] (hypothesis), kept deterministic.
    M = 6 / 7 * np.ones((N_VI, N_VI)) + 1 / 7 * np.eye(N_VI)
    q, lo, hi, radius = np.zeros(N_VI), np.zeros(2), np.zeros(2), 1.0
    y0 = np.array([1.0, 1.0, 1.0, 1.0, 0.0, 1.0])
    solver = VI_SOLVERS["newton_1"]
    sol = _vi_solve(solver)(*_vi_args((M, q, lo, hi, radius, y0, None)))
    assert sol.result == nj.RESULTS.nonlinear_max_steps_reached
    y = np.asarray(sol.value)
    assert np.all((lo <= y[:2]) & (y[:2] <= hi)) and np.all(y[2:4] >= 0)
    assert np.linalg.norm(y[4:]) <= radius * (1 + 4 * np.finfo(np.float64).eps)


def test_vi_value_in_set_when_not_converged_1d():
    def project(z, y, rho):
        ctx = nj.ProjectionContext(
            t=jnp.zeros(()), h=jnp.ones(()), y_prev=y, y_iter=y, rho=rho, args=None
        )
        return nj.NonNegative()(z, ctx)

    solver = nj.FixedPointVI(max_steps=1)
    sol = solver.solve(lambda y: 4.0 * y - 1.0, project, jnp.ones(1), jnp.array([-5.0]))
    assert sol.result == nj.RESULTS.nonlinear_max_steps_reached
    assert float(sol.value[0]) >= 0.0
