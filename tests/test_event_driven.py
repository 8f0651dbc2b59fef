"""The event-driven stepper: fifth order between events, events located on the dense
output, the new face decided by the projected problem at the event, and the event time's
sensitivity. Every reference is exact (closed form) or an independent converged run."""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq

import nivpjax as nj


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
from _references_switching import chua_reference, forced_relay_exact  # noqa: E402


# Without the time-stepping fallback (Bathe), which none of these isolated events reaches:
# a smaller program to compile. The hand-over has its own tests below.
ED = nj.EventDriven(fallback=None)


def _slope(hs, errors):
    return np.polyfit(np.log(hs), np.log(errors), 1)[0]


# --- fixed steps: order on a smooth problem and across isolated events ----------------------


def _oscillator(t, y, a):
    return jnp.stack([y[1], -y[0]])


@jax.jit
def _oscillator_run(h):
    return nj.solve(
        _oscillator,
        0.0,
        4.0,
        jnp.array([1.0, 0.0]),
        stepper=ED,
        controller=nj.ConstantStepSize(),
        h0=h,
        saveat=nj.SaveAt(),
    )


def test_fifth_order_on_a_smooth_problem():
    hs = np.array([0.4, 0.2, 0.1])
    errors = []
    for h in hs:
        sol = _oscillator_run(h)
        exact = np.array([np.cos(4.0), -np.sin(4.0)])
        errors.append(np.max(np.abs(np.asarray(sol.y_final) - exact)))
    assert _slope(hs, errors) > 4.7, errors


def _relay_field(t, y, a):
    return jnp.stack([-y[1] + 1.3 * jnp.sin(2.0 * t), y[0]])


RELAY = dict(
    projector=nj.BlockProjector([([1], nj.Box(-1.0, 1.0))]),
    mass_matrix=np.diag([1.0, 0.0]),
)


@jax.jit
def _relay_fixed(h):
    return nj.solve(
        _relay_field,
        0.0,
        4.0,
        jnp.array([0.3, 0.0]),
        stepper=ED,
        controller=nj.ConstantStepSize(),
        h0=h,
        max_steps=400,
        **RELAY,
    )


def test_fourth_order_across_crossings_sliding_entries_and_exits():
    # The forced relay x' = -w + 1.3 sin 2t, w in sign(x), x0 = 0.3 over [0, 4]: a
    # crossing phase, a sliding phase entered at 1.599 and left at 2.010 (the equivalent
    # control reaching -1), a crossing phase and a second sliding entry. Fixed steps,
    # each cut at the events: the global error falls at least at fourth order (the
    # events are located on the order-4 continuous extension).
    hs = np.array([0.2, 0.1, 0.05])
    errors = []
    for h in hs:
        sol = _relay_fixed(h)
        assert sol.result == nj.RESULTS.successful
        k = int(sol.n_accepted)
        ts = np.asarray(sol.ts[: k + 1])
        xs = np.asarray(sol.ys[: k + 1, 0])
        errors.append(np.max(np.abs(xs - forced_relay_exact(ts, 0.3, 1.3, 2.0, 4.0))))
    assert _slope(hs, errors) > 3.8, errors
    assert errors[-1] < 1e-7


# --- adaptive: events located to the tolerance ------------------------------------------------


@jax.jit
def _relay_adaptive(rtol):
    return nj.solve(
        _relay_field,
        0.0,
        8.0,
        jnp.array([0.3, 0.0]),
        stepper=nj.EventDriven(),  # the default, with its hand-over
        controller=nj.PIDController(rtol=rtol, atol=rtol / 100),
        max_steps=1000,
        t_eval=jnp.linspace(0.0, 8.0, 161),
        **RELAY,
    )


def _sliding_times():
    # Entry: the first zero of the crossing phase x = 0.3 - t + 0.65 (1 - cos 2t); exit:
    # |1.3 sin 2t| = 1, at sin 2t = -1/1.3.
    entry = brentq(lambda t: 0.3 - t + 0.65 * (1 - np.cos(2 * t)), 1.0, 1.8, xtol=1e-15)
    exit_ = (np.pi + np.arcsin(1 / 1.3)) / 2
    return entry, exit_


def test_sliding_entry_and_exit_located_and_equivalent_control():
    entry, exit_ = _sliding_times()
    errors = []
    for rtol in (1e-4, 1e-6, 1e-8):
        sol = _relay_adaptive(rtol)
        assert sol.result == nj.RESULTS.successful
        k = int(sol.n_accepted)
        ts = np.asarray(sol.ts[: k + 1])
        ys = np.asarray(sol.ys[: k + 1])
        # Both events are step ends, located to the tolerance.
        assert np.min(np.abs(ts - entry)) < 10 * rtol
        assert np.min(np.abs(ts - exit_)) < 10 * rtol
        # From the entry (its step end takes the sliding selection) to before the exit.
        sliding = (ts > entry - 10 * rtol) & (ts < exit_ - 10 * rtol)
        assert sliding.sum() >= 1
        # On the surface: x = 0 and w the equivalent control 1.3 sin 2t.
        assert np.max(np.abs(ys[sliding, 0])) < 1e-12
        np.testing.assert_allclose(ys[sliding, 1], 1.3 * np.sin(2 * ts[sliding]), atol=1e-9)
        errors.append(np.max(np.abs(ys[:, 0] - forced_relay_exact(ts, 0.3, 1.3, 2.0, 8.0))))
        # Between the steps too (the pair's continuous extension): a step over a whole
        # excursion, with both ends on the surface, would show here only (one did, at
        # a sliding exit read as sliding again from a state 7e-18 on the wrong side).
        te = np.asarray(sol.t_eval)
        exact = forced_relay_exact(te, 0.3, 1.3, 2.0, 8.0)
        errors[-1] = max(errors[-1], np.max(np.abs(np.asarray(sol.y_eval[:, 0]) - exact)))
    # Tolerance proportionality: the error follows rtol (order 5 with local error control).
    assert errors[0] < 2e-4 and errors[1] < 2e-6 and errors[2] < 2e-8, errors
    assert errors[2] < errors[1] < errors[0]


# --- a crossing with a closed-form event time, and its sensitivity ----------------------------


def _growth(t, x, a, m):
    # x' = x below x = 1 (w = -1), x' = x + c above (w = +1): the crossing at
    # t_e = ln(1 / x0), after which x + c = (1 + c) e^(t - t_e).
    return x + 0.5 * a["c"] * (1.0 + m["w"])


GROWTH = nj.Scene(_growth, 1, (nj.Relay("w", lambda t, x, a: x[:1] - 1.0),))


@jax.jit
def _growth_run(x0, c, rtol):
    sol = GROWTH.solve(
        0.0,
        3.0,
        jnp.stack([x0]),
        {"c": c},
        stepper=ED,
        controller=nj.PIDController(rtol=rtol, atol=rtol * 1e-3),
        max_steps=200,
        adjoint="forward",
    )
    return sol.y_final[0], sol


def _growth_exact(x0, c, T=3.0):
    return (1 + c) * x0 * np.exp(T) - c


def test_crossing_located_to_round_off_on_the_dense_output():
    x0, c = 0.1, 1.0
    for rtol in (1e-4, 1e-8):
        xT, sol = _growth_run(x0, c, rtol)
        k = int(sol.n_accepted)
        ts = np.asarray(sol.ts[: k + 1])
        t_e = np.log(1 / x0)
        # The event is a step end; its time carries the dense output's error only.
        assert np.min(np.abs(ts - t_e)) < rtol
        assert abs(float(xT) - _growth_exact(x0, c)) < 50 * rtol * abs(_growth_exact(x0, c))


def test_gradient_through_a_crossing_carries_the_saltation_term():
    # d x(T)/d x0 = 2 e^T (with c = 1): the event time moves with x0, and without its
    # sensitivity the derivative comes out e^T (half). d x(T)/dc = x0 e^T - 1.
    x0, c = 0.1, 1.0
    # Forward mode (a smaller program than reverse mode's; both carry the same
    # zero-in-value shifts, and reverse mode gave the same to 1e-6 when checked by hand).
    grad = jax.jacfwd(lambda a, b: _growth_run(a, b, 1e-8)[0], argnums=(0, 1))
    g_x0, g_c = (float(g) for g in grad(jnp.asarray(x0), jnp.asarray(c)))
    assert g_x0 == pytest.approx((1 + c) * np.exp(3.0), rel=1e-6)
    assert g_c == pytest.approx(x0 * np.exp(3.0) - 1, rel=1e-6)
    # And against central differences of the solver itself.
    eps = 1e-5
    fd = (float(_growth_run(x0 + eps, c, 1e-8)[0]) - float(_growth_run(x0 - eps, c, 1e-8)[0])) / (
        2 * eps
    )
    assert g_x0 == pytest.approx(fd, rel=1e-5)


# --- two crossings inside one step -----------------------------------------------------------


def _dip(t, x, a, m):
    return 0.1 * m["w"] + 2 * t - 0.5


DIP = nj.Scene(_dip, 1, (nj.Relay("w", lambda t, x, a: x[:1]),))


@jax.jit
def _dip_run(x0):
    # The selection's initial guess on its face (a theta = 0 stage from w = 0 has a
    # singular Newton matrix: its residual x does not depend on w).
    return DIP.solve(
        0.0,
        2.0,
        x0,
        multipliers={"w": jnp.ones(1)},
        stepper=ED,
        controller=nj.ConstantStepSize(),
        h0=1.0,
        max_steps=20,
    )


def test_double_crossing_inside_one_step_is_found():
    # x' = 0.1 w + 2t - 0.5, w in sign(x), x0 = 0.03: x dips below 0 on [0.1, 0.5]
    # (crossings: the flow points the same way on both sides), inside the first step of
    # length 1, whose two ends agree on the sign. Sampling the step finds the dip; the
    # flow is quadratic in t, so the events and x(2) = 3.15 are exact to round-off.
    t1, t2 = 0.1, 0.5
    sol = _dip_run(jnp.array([0.03]))
    assert sol.result == nj.RESULTS.successful
    k = int(sol.n_accepted)
    ts = np.asarray(sol.ts[: k + 1])
    assert np.min(np.abs(ts - t1)) < 1e-12 and np.min(np.abs(ts - t2)) < 1e-12
    assert float(sol.y_final[0]) == pytest.approx(3.15, abs=1e-12)


# --- Chua's circuit against an independent converged run -------------------------------------


@jax.jit
def _chua_run(rtol):
    scene, x0, args = nj.scenes.chua()
    return scene.solve(
        0.0,
        4.0,
        x0,
        args,
        stepper=ED,
        controller=nj.PIDController(rtol=rtol, atol=rtol * 1e-3),
        max_steps=2000,
    )


def test_chua_against_a_converged_run():
    _, x0, args = nj.scenes.chua()
    p = {k: float(v) for k, v in args.items()}
    ref, _ = chua_reference(
        np.asarray(x0), np.array([4.0]), p["alpha"], p["beta"], p["m0"], p["m1"]
    )
    errors = []
    for rtol in (1e-5, 1e-7, 1e-9):
        sol = _chua_run(rtol)
        assert sol.result == nj.RESULTS.successful
        errors.append(np.max(np.abs(np.asarray(sol.y_final[:3]) - ref[-1])))
    assert errors[1] < 1e-4 and errors[2] < 1e-6, errors
    assert errors[2] < errors[1] < errors[0]


# --- what it refuses, and what it does not pretend ------------------------------------------


def test_laws_on_differential_rows_are_refused_before_any_work():
    scene, x0, args = nj.scenes.spring_slider()
    with pytest.raises(ValueError, match="algebraic rows only"):
        scene.solve(0.0, 1.0, x0, args, stepper=nj.EventDriven())


@pytest.mark.parametrize("stiffness", [3.0, 300.0])
def test_hand_over_through_a_zeno_point(stiffness):
    # The Filippov spiral x' = -B w, w in sign(x), reaches its Zeno point at
    # t* = 13 / (2 S a) after infinitely many switchings: V = |x1| + |x2| falls at 2 S a
    # until then, and the state rests at the origin after. The events accumulate; the
    # steps whose first event comes within 1e-3 of them go to Bathe, which passes the
    # accumulation, and the event-driven steps come back at the origin (sliding on both
    # surfaces, w = 0 inside the box).
    scene, x0, args = nj.scenes.filippov_spiral(stiffness=stiffness)
    rate = 2 * stiffness * 0.02
    sol = scene.solve(
        0.0,
        2 * 13 / rate,
        x0,
        args,
        stepper=nj.EventDriven(),
        controller=nj.PIDController(rtol=1e-6, atol=1e-8),
        max_steps=1000,
    )
    k = int(sol.n_accepted)
    ts = np.asarray(sol.ts[: k + 1])
    ys = np.asarray(sol.ys[: k + 1])
    V = np.abs(ys[:, 0]) + np.abs(ys[:, 1])
    assert np.max(np.abs(V - np.maximum(13 - rate * ts, 0.0))) < 1e-5
    np.testing.assert_allclose(np.asarray(sol.y_final[:2]), 0.0, atol=1e-8)


def test_without_a_fallback_accumulating_switches_end_with_a_failure_code():
    scene, x0, args = nj.scenes.filippov_spiral(stiffness=3.0)
    sol = scene.solve(
        0.0,
        2 * 13 / (2 * 3.0 * 0.02),
        x0,
        args,
        stepper=ED,
        controller=nj.PIDController(rtol=1e-6, atol=1e-8),
        max_steps=300,
        throw=False,
    )
    assert sol.result != nj.RESULTS.successful


@jax.jit
def _relay_final(amplitude):
    def field(t, y, a):
        return jnp.stack([-y[1] + a * jnp.sin(2.0 * t), y[0]])

    sol = nj.solve(
        field,
        0.0,
        2.3,
        jnp.array([0.3, 0.0]),
        amplitude,
        stepper=ED,
        controller=nj.PIDController(rtol=1e-9, atol=1e-11),
        saveat=nj.SaveAt(),
        adjoint="forward",
        **RELAY,
    )
    return sol.y_final[0]


def test_gradient_through_a_sliding_entry_and_exit_matches_finite_differences():
    # x(2.3) of the forced relay after a crossing phase, a sliding phase entered at 1.599
    # and left at 2.010 (the equivalent control reaching -1: a multiplier-side event)
    # and part of an excursion: both event times move with the amplitude.
    g = float(jax.jacfwd(_relay_final)(jnp.asarray(1.3)))
    eps = 1e-6
    fd = (float(_relay_final(1.3 + eps)) - float(_relay_final(1.3 - eps))) / (2 * eps)
    assert g == pytest.approx(fd, rel=1e-6)
    assert abs(g) > 0.1
