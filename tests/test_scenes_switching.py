"""Switching scenes (relay, super-twisting, rectifiers, Chua) against independent references.

Each scene is solved once per parameter set (module-scoped fixtures share the solutions,
compiled once per scene) with the default stepper (Bathe, Richardson error estimate) and
compared with a reference computed here without nivpjax: closed forms with Brent root
finding for the relay and the rectifiers, event-driven DOP853 at rtol 1e-12 for the
super-twisting reaching phase and for Chua's circuit. Bounds are about 3x the measured
errors (stated next to each assertion) at the tolerances used.
"""

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import scene_model
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import nivpjax as nj


def _run(scene, x0, args, t1, rtol, atol, **kwargs):
    controller = nj.PIDController(rtol=rtol, atol=atol)
    sol = scene.solve(0.0, t1, x0, args, controller=controller, max_steps=20_000, **kwargs)
    assert sol.result == nj.RESULTS.successful
    trimmed = sol.trimmed()
    x, multipliers = scene.split(trimmed.ys)
    return (
        trimmed,
        np.asarray(trimmed.ts),
        np.asarray(x),
        {k: np.asarray(v) for k, v in multipliers.items()},
    )


def _first_root(g, t0, t1, dt):
    """The first sign change of `g` on a grid of spacing `dt` in (t0, t1], refined by Brent's
    method to machine precision; `None` if there is none."""
    grid = np.append(np.arange(t0, t1, dt), t1)
    values = np.array([g(t) for t in grid])
    idx = np.flatnonzero(np.sign(values[1:]) != np.sign(values[:-1]))
    if idx.size == 0:
        return None
    i = idx[0]
    return brentq(g, grid[i], grid[i + 1], xtol=1e-16, rtol=4 * np.finfo(float).eps)


# --------------------------------------------------------------------------------------
# Relay: x' = -sign(x) + a sin(2 pi f t).

RELAY, _, _ = nj.scenes.relay()
RELAY_CASES = {"a0.5_f1": (0.5, 1.0, 0.5), "a0.8_f3": (0.8, 3.0, 0.3)}


def _relay_free(t, a, f, x0):
    """x(t) before reaching (w = 1): x0 - t + a (1 - cos 2 pi f t) / (2 pi f)."""
    return x0 - t + a * (1 - np.cos(2 * np.pi * f * t)) / (2 * np.pi * f)


@pytest.fixture(scope="module", params=list(RELAY_CASES))
def relay_run(request):
    a, f, x0 = RELAY_CASES[request.param]
    args = {"amplitude": jnp.asarray(a), "frequency": jnp.asarray(f)}
    # x' <= -(1 - |a|) < 0 while x > 0: a unique reaching time below x0 / (1 - |a|).
    T = brentq(_relay_free, 1e-12, x0 / (1 - abs(a)), args=(a, f, x0), xtol=1e-16, rtol=1e-15)
    run = _run(RELAY, jnp.asarray([x0]), args, 3.0, 1e-6, 1e-9)
    return (a, f, x0, T), run


def test_relay_reaching_time(relay_run):
    (a, f, x0, T), (sol, ts, x, m) = relay_run
    x = x[:, 0]
    k = np.flatnonzero(np.abs(x) < 1e-15)[0]  # the first accepted state on the surface
    # The landing brackets the reaching time up to the free phase's global error: x is
    # off by -1.36e-5 (a0.5) and -5.1e-6 (a0.8) just before it (measured with Bathe's
    # embedded estimate at rtol 1e-6, within the free-motion bound 3e-5), so the numerical
    # trajectory reaches x = 0 earlier by that over |x'|: 9.9e-6 and 3.7e-6. A strict
    # T <= ts[k] held only for a global error >= 0 there.
    assert ts[k - 1] < T + 2e-5 and T - 2e-5 <= ts[k]
    # First-order extrapolation from the last state before reaching, with the exact slope
    # -1 + d(t): the numerical reaching time. Measured |error| <= 6.5e-6.
    t_reach = ts[k - 1] + x[k - 1] / (1 - a * np.sin(2 * np.pi * f * ts[k - 1]))
    assert abs(t_reach - T) < 2e-5


def test_relay_free_motion(relay_run):
    (a, f, x0, T), (sol, ts, x, m) = relay_run
    # Before the numerical landing (up to 1e-5 before T, see test_relay_reaching_time).
    before = ts < ts[np.flatnonzero(np.abs(x[:, 0]) < 1e-15)[0]]
    # Measured max error 9.3e-6 (a0.5) and 6.3e-6 (a0.8) at rtol 1e-6.
    np.testing.assert_allclose(x[before, 0], _relay_free(ts[before], a, f, x0), rtol=0, atol=3e-5)
    # The selection is the relay's value sign(x) = 1 on every accepted state before reaching
    # (entry 0 is the user's initial guess, not a computed value).
    np.testing.assert_allclose(m["w"][1:][before[1:], 0], 1.0, rtol=0, atol=1e-12)


def test_relay_filippov_sliding(relay_run):
    (a, f, x0, T), (sol, ts, x, m) = relay_run
    np.testing.assert_allclose(x[ts > T, 0], 0.0, rtol=0, atol=1e-12)
    # Sliding on x = 0 with the equivalent control w = d(t) (measured <= 2.2e-16) at
    # every state after the reaching step (whose w averages the relay value 1 before T and
    # d after it over the step).
    after = ts > ts[np.flatnonzero(np.abs(x[:, 0]) < 1e-15)[0]]
    assert after.sum() >= 2
    d = a * np.sin(2 * np.pi * f * ts[after])
    np.testing.assert_allclose(m["w"][after, 0], d, rtol=0, atol=1e-10)
    # The selection always lies in sign's convex hull [-1, 1].
    assert np.all(np.abs(m["w"]) <= 1.0 + 1e-14)


# --------------------------------------------------------------------------------------
# A relay with bounds [l, u]: w = u where s > 0, w = l where s < 0.


def _bounded_relay_dynamics(t, x, a, m):
    return 1.75 + jnp.sin(t) - m["w"]


BOUNDED_RELAY = nj.Scene(
    _bounded_relay_dynamics, 1, (nj.Relay("w", lambda t, x, a: x[:1], lower=0.5, upper=3.0),)
)


def test_relay_bounds_reaching_and_sliding():
    """x' = u(t) - w, u = 1.75 + sin t in [0.75, 2.75], w in [0.5, 3] on s = x, x0 = 0.5:
    x' = u - 3 < 0 until x reaches 0 at T (x0 + 1 - cos T - 1.25 T = 0), then it slides
    with the equivalent control w = u(t), inside the bounds (a selection [-1, 1] cannot
    hold it: x' >= 0.75 - 1 there is not enough)."""
    T = brentq(lambda t: 0.5 + 1 - np.cos(t) - 1.25 * t, 1e-9, 2.0, xtol=1e-16)
    _, ts, x, m = _run(BOUNDED_RELAY, jnp.asarray([0.5]), None, 3.0, 1e-6, 1e-9)
    x, w = x[:, 0], m["w"][:, 0]
    on = np.flatnonzero(np.abs(x) < 1e-12)[0]  # the first accepted state on the surface
    before, after = ts < ts[on], ts > ts[on]
    exact = 0.5 + 1 - np.cos(ts[before]) - 1.25 * ts[before]
    # Measured at rtol 1e-6: free motion off by 2.8e-6, landing 3.7e-6 before T, w = u(t)
    # to 3e-16 while sliding.
    np.testing.assert_allclose(x[before], exact, rtol=0, atol=1e-5)
    assert abs(ts[on] - T) < 2e-5 and after.sum() >= 2
    np.testing.assert_allclose(w[1:][before[1:]], 3.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(x[after], 0.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(w[after], 1.75 + np.sin(ts[after]), rtol=0, atol=1e-10)
    assert np.all((w >= 0.5 - 1e-12) & (w <= 3.0 + 1e-12))


def test_relay_bounds_equal_the_scaled_sign_relay():
    """Two relays with bounds [l, u] per component, forced so that they slide, leave the
    surface and cross it, against the same system written with a sign relay v in [-1, 1]
    and w = l + (u - l)(v + 1)/2."""
    lower, upper = np.array([-0.6, -0.5]), np.array([1.0, 2.0])
    force = lambda t: jnp.array([1.3 * jnp.sin(2 * t), 0.8 + 1.5 * jnp.sin(3 * t)])  # noqa: E731
    switch = lambda t, x, a: x  # noqa: E731
    bounded = nj.Scene(
        lambda t, x, a, m: force(t) - m["w"],
        2,
        (nj.Relay("w", switch, n=2, lower=jnp.asarray(lower), upper=jnp.asarray(upper)),),
    )
    scaled = nj.Scene(
        lambda t, x, a, m: force(t) - (lower + (upper - lower) * (m["v"] + 1) / 2),
        2,
        (nj.Relay("v", switch, n=2),),
    )
    t_eval = jnp.linspace(0.0, 6.0, 61)
    x0 = jnp.array([0.3, -0.2])
    ys = [
        np.asarray(_run(s, x0, None, 6.0, 1e-6, 1e-9, t_eval=t_eval)[0].y_eval[:, :2])
        for s in (bounded, scaled)
    ]
    # Both components move and slide (x = 0 at 10% and 38% of the outputs).
    assert np.ptp(ys[0], axis=0).min() > 0.2
    assert np.all(np.mean(np.abs(ys[0]) < 1e-9, axis=0) > 0.05)
    # Measured difference 1.5e-7 (about 1350 steps each).
    np.testing.assert_allclose(ys[0], ys[1], rtol=0, atol=1e-6)


# --------------------------------------------------------------------------------------
# Super-twisting: sigma = x2 + c x1, u = -k1 sqrt|sigma| w + nu, nu' = -k2 w.

ST, ST_X0, ST_ARGS = nj.scenes.super_twisting()
ST_K1, ST_K2, ST_C = (float(ST_ARGS[k]) for k in ("k1", "k2", "c"))


def _st_disturbance(t):
    return 0.3 * np.sin(5.0 * t), 1.5 * np.cos(5.0 * t)  # d, d'


def _st_reference(x0, t1):
    """Event-driven reference: w = sign(sigma) is constant between zero crossings of sigma
    (transversal: sigma' = nu + d + c x2 is continuous and nonzero there), each segment
    solved by DOP853 at rtol 1e-12 up to the next crossing. The crossings accumulate in
    finite time (the twisting); the accumulation point T* is the reaching time. Returns the
    segments' dense outputs, the crossing times and T*."""
    c, k1, k2 = ST_C, ST_K1, ST_K2

    def rhs(w):
        def f(t, x):
            s = x[1] + c * x[0]
            u = -k1 * np.sqrt(abs(s)) * w + x[2]
            return [x[1], u + _st_disturbance(t)[0], -k2 * w]

        return f

    t, x = 0.0, np.asarray(x0, float)
    w = np.sign(x[1] + c * x[0])
    segments, crossings = [], []
    while True:
        event = lambda t, x: x[1] + c * x[0]
        event.terminal, event.direction = True, -w
        sol = solve_ivp(
            rhs(w),
            (t, t1),
            x,
            method="DOP853",
            rtol=1e-12,
            atol=1e-14,
            events=event,
            dense_output=True,
        )
        segments.append((t, sol.t[-1], sol.sol))
        assert sol.status == 1, "no reaching before t1"
        t, x = sol.t_events[0][0], sol.y_events[0][0]
        crossings.append(t)
        w = -w
        # Peak |sigma| between crossings falls by orders of magnitude each half-turn; stop
        # once two crossings are within 1e-9 (the remaining twisting is shorter than that).
        if len(crossings) > 1 and crossings[-1] - crossings[-2] < 1e-9:
            return segments, np.array(crossings), t


@pytest.fixture(scope="module")
def st_run():
    segments, crossings, T = _st_reference(np.asarray(ST_X0), 10.0)
    xT = segments[-1][2](T)
    run = _run(ST, ST_X0, ST_ARGS, 10.0, 1e-6, 1e-8, save_attempts=True)
    ts = run[1]
    reference = np.empty((ts.size, 3))
    for i, t in enumerate(ts):
        if t >= T:
            # Sliding (sigma = 0): x1' = -c x1, x2 = -c x1, and sigma' = 0 gives
            # nu = -d(t) - c x2 (equivalent control).
            x1 = xT[0] * np.exp(-ST_C * (t - T))
            reference[i] = [x1, -ST_C * x1, -_st_disturbance(t)[0] + ST_C**2 * x1]
        else:
            reference[i] = next(s(t) for a, b, s in segments if a <= t <= b)
    return (crossings, T, reference), run


def _st_reach_index(ts, x):
    """The first accepted state from which on sigma is 0 to rounding (|sigma| <= 1e-14)."""
    sigma = x[:, 1] + ST_C * x[:, 0]
    return np.flatnonzero(np.abs(sigma) > 1e-14)[-1] + 1


def test_super_twisting_reaching_phase(st_run):
    (crossings, T, reference), (sol, ts, x, m) = st_run
    # At least four transversal crossings of sigma = 0 before the sliding mode.
    assert crossings.size >= 5 and np.all(np.diff(crossings[:5]) > 1e-3)
    before = ts < T
    err = np.max(np.abs(x[before] - reference[before]), axis=0)
    # Measured (x1, x2, nu): up to 1.5e-4, 2.5e-4, 1.7e-3 at rtol 1e-6. nu' = -k2 w integrates the
    # sign jumps: a crossing inside a step shifts nu by O(k2 h), which step doubling does not
    # always see (see the library report); x1, x2 inherit it.
    np.testing.assert_array_less(err, [5e-4, 8e-4, 5e-3])
    # w is the relay value sign(sigma) wherever |sigma| is resolved away from 0.
    sigma = x[:, 1] + ST_C * x[:, 0]
    away = before & (np.abs(sigma) > 1e-3)
    away[0] = False  # initial guess
    np.testing.assert_allclose(m["w"][away, 0], np.sign(sigma[away]), rtol=0, atol=1e-12)


def test_super_twisting_finite_time_sliding(st_run):
    (crossings, T, reference), (sol, ts, x, m) = st_run
    k = _st_reach_index(ts, x)
    # sigma is 0 to rounding (|sigma| <= 1e-14) from ts[k] on, in finite time: ts[k] vs the
    # accumulation point of the reference's crossings. Measured 3.2e-4 to 1.4e-3 as the
    # controller changed: the numerical twisting lags by the reaching-phase error of nu.
    assert abs(ts[k] - T) < 5e-3
    assert ts[-1] - ts[k] > 7.0
    after = slice(k, None)
    # States in sliding vs x1(T*) exp(-c (t - T*)) (measured 1.4e-5 to 4.7e-5: the
    # reaching-phase error carried by x1; nu's error is forgotten on the surface).
    np.testing.assert_allclose(x[after], reference[after], rtol=0, atol=1.5e-4)
    # nu -> -d(t): nu + d = c^2 x1 -> 0 (measured 2.4e-5 at t = 10; c^2 x1(10) = 2.4e-5).
    d, _ = _st_disturbance(ts[-1])
    assert abs(x[-1, 2] + d) < 5e-5


def test_super_twisting_no_chattering(st_run):
    (crossings, T, reference), (sol, ts, x, m) = st_run
    # From 1e-3 after landing on sigma = 0 (the one or two landing steps, of ~1e-6, mix +-1
    # and the sliding value) ...
    k = _st_reach_index(ts, x)
    k = np.flatnonzero(ts > ts[k] + 1e-3)[0]
    t, w, x2 = ts[k:], m["w"][k:, 0], x[k:, 1]
    # ... the selection is the smooth equivalent control nu' = -k2 w with
    # nu = -d - c x2: w_eq = (d' - c^2 x2) / k2 (|w_eq| < 1), not a +-1 chatter.
    w_eq = (_st_disturbance(t)[1] - ST_C**2 * x2) / ST_K2
    assert np.max(np.abs(w_eq)) < 1
    np.testing.assert_allclose(w, w_eq, rtol=0, atol=0.1)  # measured 0.003 to 0.029
    # Its total variation matches the equivalent control's (measured 22.6 vs 22.4).
    tv, tv_eq = np.sum(np.abs(np.diff(w))), np.sum(np.abs(np.diff(w_eq)))
    assert tv < 1.05 * tv_eq


@pytest.mark.xfail(
    reason="Known, open: in super-twisting sliding nu is tied to d(t) by a hidden (index-2) "
    "constraint and carries a ~1.6e-4 offset; Bathe's embedded estimate on that row does not "
    "scale like h^3, so PID cycles reject/accept (~700 rejections; none with the former "
    "Richardson estimate). Needs index-aware error scaling.",
    strict=False,
)
def test_super_twisting_steps_set_by_disturbance(st_run):
    (crossings, T, reference), (sol, ts, x, m) = st_run
    k = _st_reach_index(ts, x)
    k = np.flatnonzero(ts > ts[k] + 1e-3)[0]
    t = ts[k:]
    # The steps are set by d(t), not by switching: no rejection after the first 0.1 time
    # units of sliding (measured none at all) and no step below 1.5e-2 (measured 4.4e-2).
    attempts = sol.attempts
    n = int(sol.n_accepted + sol.n_rejected)
    late = np.asarray(attempts.t[:n]) > ts[k] + 0.1
    assert np.all(np.asarray(attempts.accepted[:n])[late])
    assert np.min(np.asarray(sol.hs)[k + 1 :][t[1:] > ts[k] + 0.1]) > 1.5e-2


# --------------------------------------------------------------------------------------
# Rectifiers: source V sin(wt) (half-wave) or |V sin(wt)| (bridge) charging an RC load.

RECTIFIERS = {
    "half_wave_rectifier": (nj.scenes.half_wave_rectifier(), False),
    "diode_bridge": (nj.scenes.diode_bridge(), True),
}


class RectifierReference:
    """The exact piecewise solution: off, C v' = -v/R_L; on, C v' = (s V sin wt - v)/R_s -
    v/R_L (s = +-1 the sign of the conducting half-wave), both solved in closed form; the
    switches are the roots of src(t) - v(t) (on when the source exceeds the load voltage,
    off when the diode current (src - v)/R_s returns to 0), located by Brent's method."""

    def __init__(self, V, omega, R_s, R_L, C, t1, full):
        self.V, self.omega, self.R_s, self.R_L, self.C, self.full = V, omega, R_s, R_L, C, full
        self.a = 1 / (R_s * C) + 1 / (R_L * C)
        self.pieces = []  # (t_start, t_end, sign of the conducting half-wave or 0, v_start)
        t, v, on = 0.0, 0.0, True  # v = src = 0 at t = 0 with the source rising
        dt = 2 * np.pi / omega / 4000
        while t < t1:
            s = (1.0 if np.sin(omega * (t + dt)) > 0 or not full else -1.0) if on else 0.0
            g = lambda tt, p=(t, 0.0, s, v): self.src(tt) - self._piece(p, tt)
            end = _first_root(g, t + dt / 10, t1, dt)
            end = t1 if end is None else end
            self.pieces.append((t, end, s, v))
            t, v, on = end, self._piece(self.pieces[-1], end), not on

    def src(self, t):
        e = self.V * np.sin(self.omega * t)
        return np.abs(e) if self.full else e

    def _piece(self, piece, t):
        t0, _, s, v0 = piece
        if s == 0:
            return v0 * np.exp(-(t - t0) / (self.R_L * self.C))
        # Particular solution P sin + Q cos of v' = -a v + b sin(wt), b = s V / (R_s C).
        a, w, b = self.a, self.omega, s * self.V / (self.R_s * self.C)
        P, Q = a * b / (a * a + w * w), -w * b / (a * a + w * w)
        vp = lambda tt: P * np.sin(w * tt) + Q * np.cos(w * tt)
        return vp(t) + (v0 - vp(t0)) * np.exp(-a * (t - t0))

    def v(self, ts):
        return np.array(
            [next(self._piece(p, t) for p in self.pieces if p[0] <= t <= p[1]) for t in ts]
        )

    def conduction(self):
        return np.array([(p[0], p[1]) for p in self.pieces if p[2] != 0])


@pytest.fixture(scope="module", params=list(RECTIFIERS))
def rectifier_run(request):
    (scene, x0, args), full = RECTIFIERS[request.param]
    p = {k: float(v) for k, v in args.items()}
    t1 = 3 * 2 * np.pi / p["omega"]  # three periods
    reference = RectifierReference(p["V"], p["omega"], p["R_s"], p["R_L"], p["C"], t1, full)
    return (p, reference), _run(scene, x0, args, t1, 1e-6, 1e-9)


def _switch_times(ts, v, i, p, src):
    """Zero crossings of src(t) - v(t), with v between accepted points the cubic Hermite
    interpolant of v_k and v'_k = (sum i_k - v_k / R_L) / C (from the computed currents)."""
    dv = (i.sum(axis=1) - v / p["R_L"]) / p["C"]
    g = src(ts) - v
    out = []
    for k in np.flatnonzero((g[1:] > 0) != (g[:-1] > 0)):
        t0, h = ts[k], ts[k + 1] - ts[k]

        def gap(t, k=k, t0=t0, h=h):
            s = (t - t0) / h
            h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
            h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
            vi = h00 * v[k] + h10 * h * dv[k] + h01 * v[k + 1] + h11 * h * dv[k + 1]
            return src(t) - vi

        out.append(brentq(gap, t0, ts[k + 1], xtol=1e-15))
    return np.array(out)


def test_rectifier_voltage(rectifier_run):
    (p, reference), (sol, ts, x, m) = rectifier_run
    v = x[:, 0]
    # Measured max |v - v_ref| on the accepted steps: 2.5e-6 to 6.4e-6.
    np.testing.assert_allclose(v, reference.v(ts), rtol=0, atol=2e-5)


def test_rectifier_conduction_intervals(rectifier_run):
    (p, reference), (sol, ts, x, m) = rectifier_run
    v, i = x[:, 0], m["i"]
    intervals = reference.conduction()
    assert len(intervals) == (6 if i.shape[1] == 2 else 3)
    # The first interval starts at t = 0 (v = src = 0, source rising): compare the others'
    # starts and every end. Measured max error: 6e-8 to 1.1e-7 s, and once 2.4e-6 s (a
    # bridge start inside a 0.17 ms step), for conduction intervals 1.5 to 5.2 ms long.
    expected = np.sort(np.concatenate([intervals[1:, 0], intervals[:, 1]]))
    expected = expected[expected < ts[-1] - 1e-9]
    got = _switch_times(ts[1:], v[1:], i[1:], p, reference.src)
    assert got.shape == expected.shape
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-5)


def test_rectifier_currents(rectifier_run):
    (p, reference), (sol, ts, x, m) = rectifier_run
    v, i = x[1:, 0], m["i"][1:]
    e = p["V"] * np.sin(p["omega"] * ts[1:])
    # Complementarity at every accepted state: i = max(0, (+-e - v) / R_s) per diode pair.
    signs = np.array([1.0, -1.0])[: i.shape[1]]
    np.testing.assert_allclose(
        i, np.maximum(0.0, (signs * e[:, None] - v[:, None]) / p["R_s"]), rtol=0, atol=1e-12
    )
    assert np.all(i >= -1e-15)
    if i.shape[1] == 2:
        assert np.all(np.min(i, axis=1) <= 1e-15)  # never both pairs at once
    # Total current vs the reference's (measured 2.2e-6 to 6.4e-6 A).
    i_ref = np.maximum(0.0, (reference.src(ts[1:]) - reference.v(ts[1:])) / p["R_s"])
    np.testing.assert_allclose(i.sum(axis=1), i_ref, rtol=0, atol=2e-5)


# --------------------------------------------------------------------------------------
# Chua's circuit: piecewise-linear diode, kinks at |x| = 1.

CHUA, CHUA_X0, CHUA_ARGS = nj.scenes.chua()


def chua_reference(x0, t_eval, alpha, beta, m0, m1):
    """DOP853 at rtol 1e-13 on each linear region (|x| < 1, x > 1, x < -1), restarted at
    the kinks found as terminal events on x = +-1: no step straddles a kink."""
    t_eval = np.asarray(t_eval)

    def rhs(region):
        def f(t, u):
            sat = u[0] if region == 0 else float(region)
            g = m0 * u[0] + (m1 - m0) * sat
            return [alpha * (u[1] - u[0] - g), u[0] - u[1] + u[2], -beta * u[1]]

        return f

    def boundary(level, direction):
        event = lambda t, u: u[0] - level
        event.terminal, event.direction = True, direction
        return event

    t, u = 0.0, np.asarray(x0, float)
    region = 0 if abs(u[0]) < 1 else int(np.sign(u[0]))
    out, crossings = np.empty((t_eval.size, 3)), []
    while True:
        if region == 0:
            events = [boundary(1.0, 1), boundary(-1.0, -1)]
        else:
            events = [boundary(float(region), -region)]
        sol = solve_ivp(
            rhs(region),
            (t, t_eval[-1]),
            u,
            method="DOP853",
            rtol=1e-13,
            atol=1e-15,
            events=events,
            dense_output=True,
        )
        inside = (t_eval >= t) & (t_eval <= sol.t[-1])
        if inside.any():
            out[inside] = sol.sol(t_eval[inside]).T
        if sol.status != 1:
            return out, np.array(crossings)
        t = next(te[0] for te in sol.t_events if te.size)
        u = sol.sol(t)
        u[0] = np.round(u[0])  # exactly on the kink
        crossings.append(t)
        region = 0 if region != 0 else int(u[0])


@pytest.fixture(scope="module")
def chua_run():
    # [0, 10]: eleven kink crossings (the first at t = 5.13) while a 1e-9 perturbation of
    # x0 grows only to 3e-8.
    run = _run(CHUA, CHUA_X0, CHUA_ARGS, 10.0, 1e-8, 1e-10)
    p = {k: float(v) for k, v in CHUA_ARGS.items()}
    reference, crossings = chua_reference(np.asarray(CHUA_X0), run[1], **p)
    return (reference, crossings), run


def test_chua_trajectory(chua_run):
    (reference, crossings), (sol, ts, x, m) = chua_run
    assert crossings.size == 11
    # Measured max |x - x_ref| 6.3e-5 over [0, 10] and 3.0e-5 over [0, 5] (before the first
    # kink) at rtol 1e-8, in 6740 steps: Bathe is second order and the flow is unstable.
    np.testing.assert_allclose(x, reference, rtol=0, atol=2.5e-4)
    np.testing.assert_allclose(x[ts < 5.0], reference[ts < 5.0], rtol=0, atol=1e-4)


def test_chua_kinks(chua_run):
    (reference, crossings), (sol, ts, x, m) = chua_run
    # The saturation multiplier is clip(x, -1, 1) at every computed state: to round-off
    # except at the states where a step lands just short of a kink (event prediction stops
    # a relative 1e-8 short), where it may already carry the kink's selection: measured one
    # state of 10749 at 3.7e-9, and one of 10743 at 1.0e-8 once the first step is chosen
    # from the consistent initial rate (a different step sequence).
    np.testing.assert_allclose(m["sat"][1:, 0], np.clip(x[1:, 0], -1, 1), rtol=0, atol=3e-8)
    exact = np.abs(m["sat"][1:, 0] - np.clip(x[1:, 0], -1, 1)) <= 1e-12
    assert np.mean(exact) > 0.999
    # Kink crossings: linear interpolation of |x| - 1 between accepted points (measured
    # max error 4.1e-6).
    g = np.abs(x[:, 0]) - 1
    k = np.flatnonzero((g[1:] > 0) != (g[:-1] > 0))
    got = ts[k] - g[k] * (ts[k + 1] - ts[k]) / (g[k + 1] - g[k])
    assert got.shape == crossings.shape
    np.testing.assert_allclose(got, crossings, rtol=0, atol=2e-5)


def _event_time(scene, y0, y1, h):
    # The model's predicted time from the step's start to its first event (`next_event`),
    # for one step of size h from t = 0.
    model = scene_model(scene)
    return float(model.next_event(jnp.asarray(h), h, jnp.asarray(y0), jnp.asarray(y1), None))


def test_saturation_and_diode_events_are_their_switches():
    # The event surfaces of the scene effects change sign exactly where the law switches,
    # so the controller sees the switch. u(t) = x rising or falling at rate 1 through a
    # saturation's bound at half the step: the secant of the surface is exact for a linear
    # signal, tau = h / 2, at either bound. A diode behind a series resistor R (voltage
    # x - R i) turning off as its source x falls through 0 at half the step: the voltage
    # it would see without current changes sign there (with its current, the voltage is 0
    # while it conducts: no sign change, no event).
    h = 0.2
    for rate, x0, x1, s0, s1 in ((1.0, 0.9, 1.1, 0.9, 1.0), (-1.0, -0.9, -1.1, -0.9, -1.0)):
        sat = nj.Saturation("s", lambda t, x, a: x[:1])
        scene = nj.Scene(lambda t, x, a, m, r=rate: jnp.full(1, r), 1, (sat,))
        tau = _event_time(scene, [x0, s0], [x1, s1], h)
        np.testing.assert_allclose(tau, h / 2, rtol=1e-12)
    R = 2.0
    diode = nj.Diode("i", lambda t, x, i, a: x[:1] - R * i)
    scene = nj.Scene(lambda t, x, a, m: -jnp.ones(1), 1, (diode,))
    tau = _event_time(scene, [0.1, 0.1 / R], [-0.1, 0.0], h)
    np.testing.assert_allclose(tau, h / 2, rtol=1e-12)
