"""Embedded error estimates against the true local error of one step.

The reference is an independent solver (diffrax Tsit5 at tolerance 1e-13) from the same
start: on a smooth forced Duffing-type oscillator the estimate of every built-in stepper
must track the true local error over a ladder of step sizes, and both must converge with
the stepper's error order.
"""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj
from nivpjax._model import Model


def field(t, y, args):
    return jnp.stack([y[1], -y[0] - 0.1 * y[1] ** 3 + jnp.sin(2 * t)])


T0 = 0.2
Y0 = jnp.array([1.0, 0.3])
HS = np.array([0.2, 0.1, 0.05, 0.025])
MODEL = Model(
    vector_field=field, projector=nj.Identity(), mass_matrix=None, algebraic=jnp.zeros(2, bool)
)
TIGHT = nj.SemismoothNewton(rtol=1e-13, atol=1e-14)


@jax.jit
def _exact(h):
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field),
        diffrax.Tsit5(),
        T0,
        T0 + h,
        None,
        Y0,
        stepsize_controller=diffrax.PIDController(rtol=1e-13, atol=1e-13),
        max_steps=10_000,
    )
    return sol.ys[-1]


@pytest.fixture(scope="module")
def exact():
    return {h: np.asarray(_exact(jnp.asarray(h))) for h in HS}


# (stepper, local-error order, band of est/true over the ladder, measured in brackets)
CASES = {
    "be": (nj.BackwardEuler(TIGHT), 2),  # ratios 1.06 -> 1.00
    "tr": (nj.Trapezoidal(TIGHT), 3),  # 1.22 -> 1.03
    "theta0.7": (nj.Theta(0.7, TIGHT), 2),  # 1.17 -> 1.01
    "bathe": (nj.Bathe(solver=TIGHT), 3),  # 1.00
    "trbdf2": (nj.Bathe(2 - np.sqrt(2), TIGHT), 3),  # 1.02 -> 1.00
}


def _against_exact(stepper, exact):
    """Over the ladder of steps from (T0, Y0): the cosine between each step's true local
    error (computed minus exact) and its estimate, and the two errors' norms."""
    step = jax.jit(lambda h: stepper.step(MODEL, jnp.asarray(T0), h, Y0, None))
    cosines, true, est = [], [], []
    for h in HS:
        out = step(jnp.asarray(h))
        error, estimate = np.asarray(out.y1) - exact[h], np.asarray(out.y_error)
        cosines.append(error @ estimate / (np.linalg.norm(error) * np.linalg.norm(estimate)))
        true.append(np.linalg.norm(error))
        est.append(np.linalg.norm(estimate))
    return np.array(cosines), np.array(true), np.array(est)


@pytest.mark.parametrize("name", list(CASES))
def test_estimate_tracks_local_error(name, exact):
    stepper, order = CASES[name]
    assert stepper.error_order == order
    cosines, true, est = _against_exact(stepper, exact)
    # The estimate is the computed state minus the exact one, direction included
    # (the trapezoidal rule's had the opposite sign).
    assert np.all(cosines > 0.95), cosines
    ratio = est / true
    assert np.all((0.8 <= ratio) & (ratio <= 1.35)), ratio
    assert 0.9 <= ratio[-1] <= 1.1, ratio  # asymptotically exact
    # Orders from the two smallest steps: the true error's and the estimate's.
    for e in (true, est):
        measured = np.log2(e[-2] / e[-1])
        assert abs(measured - order) <= 0.2, (measured, order)


# Richardson step doubling around a scheme of order p propagates the two half steps and
# estimates their error as (y_{h/2,h/2} - y_h)/(2^p - 1). (Its sign is the other way round
# from the embedded estimates': exact minus computed. Only its norm is used.)
RICHARDSON = {
    "be": (nj.Richardson(nj.BackwardEuler(TIGHT)), 2),
    "tr": (nj.Richardson(nj.Trapezoidal(TIGHT)), 3),
}


@pytest.mark.parametrize("name", list(RICHARDSON))
def test_richardson_estimate_tracks_local_error(name, exact):
    stepper, order = RICHARDSON[name]
    assert stepper.error_order == order
    cosines, true, est = _against_exact(stepper, exact)
    assert np.all(cosines < -0.95), cosines  # the other sign, see above
    ratio = est / true
    assert 0.85 <= ratio[-1] <= 1.15, ratio  # asymptotically exact
    measured = np.log2(est[-2] / est[-1])
    assert abs(measured - order) <= 0.2, (measured, order)


# An index-1 DAE: the half-wave rectifier while its diode conducts, i = (V sin wt - v)/R_s,
# from a start far off the quasi-steady state (the fast mode R_s C = 1e-4 s dominates the
# error). The current is an equation row: its rate must enter the estimate (the trapezoidal
# rule's was 500x too small, backward Euler's 1000x, while a secant or the end's current
# stood for it), and the reference is the reduced ODE for v alone.
RECT_T0, RECT_V0 = 0.004, 0.2
RECT_HS = np.array([2e-5, 1e-5, 5e-6, 2.5e-6])


def _rectifier():
    from nivpjax._model import Model

    scene, _, args = nj.scenes.half_wave_rectifier()
    model = Model.build(
        scene.vector_field,
        scene.projector,
        scene.full_mass_matrix,
        [False, True],
        equation_rows=scene.equation_rows,
    )
    return model, {k: float(v) for k, v in args.items()}


@pytest.fixture(scope="module")
def rectifier():
    model, p = _rectifier()

    def reduced(t, v, _):
        source = p["V"] * jnp.sin(p["omega"] * t)
        return ((source - v) / p["R_s"] - v / p["R_L"]) / p["C"]

    @jax.jit
    def exact(h):
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(reduced),
            diffrax.Tsit5(),
            RECT_T0,
            RECT_T0 + h,
            h / 50,
            jnp.array([RECT_V0]),
            stepsize_controller=diffrax.PIDController(rtol=1e-13, atol=1e-15),
            max_steps=10_000,
        )
        return sol.ys[-1, 0]

    i0 = (p["V"] * np.sin(p["omega"] * RECT_T0) - RECT_V0) / p["R_s"]
    y0 = jnp.array([RECT_V0, i0])
    return model, p, y0, {h: float(exact(jnp.asarray(h))) for h in RECT_HS}


@pytest.mark.parametrize("name", list(CASES))
def test_estimate_sees_an_equation_row(name, rectifier):
    model, args, y0, exact = rectifier
    stepper, order = CASES[name]
    step = jax.jit(lambda h: stepper.step(model, jnp.asarray(RECT_T0), h, y0, args))
    true, est = [], []
    for h in RECT_HS:
        out = step(jnp.asarray(h))
        true.append(float(out.y1[0]) - exact[h])
        est.append(float(out.y_error[0]))
    ratio = np.array(est) / np.array(true)
    # Measured: 1.14 -> 1.02 (backward Euler), 1.10 -> 1.01 (trapezoidal), 1.13 -> 1.02
    # (theta 0.7), 1.07 -> 1.01 (Bathe, TR-BDF2).
    assert np.all((0.9 <= ratio) & (ratio <= 1.25)), ratio
    assert 0.95 <= ratio[-1] <= 1.05, ratio
    for e in (np.abs(true), np.abs(est)):
        measured = np.log2(e[-2] / e[-1])
        assert abs(measured - order) <= 0.2, (measured, order)


def test_departure_error_is_the_computed_minus_the_exact_motion():
    # z' = c (t - t_d) in the box [-1, 1], held at -1 while the field pushes out (t < t_d):
    # from t0 on the face, the exact state at t1 is -1 + c (t1 - t_d)^2 / 2. The charge is
    # the computed state minus that, whether the step ended on the face (the trapezoidal
    # rule) or moved off it (Bathe's backward-difference stage); zero with no departure.
    from nivpjax._stepper.departure import departure_error

    c, t0, h, td = 2.0, 0.3, 0.5, 0.45
    t1 = t0 + h

    def field(t, y, args):
        return c * (t - td) * jnp.ones_like(y)

    box = nj.BlockProjector([([0], nj.Box(-1.0, 1.0))])
    model = Model.build(field, box, None, np.zeros(1, bool))
    assert model.has_held_rows
    y0 = jnp.array([-1.0])
    exact = -1.0 + 0.5 * c * (t1 - td) ** 2

    def charge(y0, y1, ta=t0):
        f0, f1 = field(ta, y0, None), field(ta + h, y1, None)
        return float(departure_error(model, ta, h, y0, y1, f0, f1, None)[0])

    for y1 in (-1.0, -0.8):
        np.testing.assert_allclose(charge(y0, jnp.array([y1])), y1 - exact, rtol=1e-12)
    assert charge(y0, jnp.array([-1.0]), ta=-0.3) == 0.0  # pushed out at both ends: held
    assert charge(jnp.array([0.0]), jnp.array([0.1])) == 0.0  # free at the start


def test_theta_estimate_charges_a_switch_inside_the_step():
    # x' = -w + 2, w in Sign(x), from x0 < 0: x' = 3 until x = 0 at tau, then 1 (the flow
    # crosses), so x(h) = x0 + h + 2 tau. The trapezoidal rule collocates w at t1: it
    # crosses with the averaged rate 2 where tau < 2h/3, and lands on x = 0 (w inside
    # (-1, 1)) after. Its estimate must cover the true error at every tau. A multipliers'
    # secant across the switch lets the flow's derivative explain the jump of w away
    # (measured: 0.0025 against a true 0.03 at tau = 0.65 h, 0.019 against 0.025 at 0.75 h).
    scene = nj.Scene(lambda t, x, a, m: -m["w"] + 2.0, 1, (nj.Relay("w", lambda t, x, a: x),))
    model = Model.build(
        scene.vector_field, scene.projector, scene.full_mass_matrix, np.array([False, True])
    )
    h = 0.1
    step = jax.jit(lambda y0: nj.Trapezoidal(TIGHT).step(model, jnp.asarray(0.0), h, y0, None))
    for fraction in (0.3, 0.55, 0.65, 0.75, 0.9):
        x0 = -3.0 * fraction * h  # tau = fraction * h
        out = step(jnp.array([x0, -1.0]))
        true = float(out.y1[0]) - (x0 + h + 2 * fraction * h)
        assert abs(float(out.y_error[0])) >= abs(true), (fraction, out.y_error, true)


def _crossing_relay():
    # The flow of the test above, x' = 3 until x = 0 at tau, then 1.
    scene = nj.Scene(lambda t, x, a, m: -m["w"] + 2.0, 1, (nj.Relay("w", lambda t, x, a: x),))
    return Model.build(
        scene.vector_field, scene.projector, scene.full_mass_matrix, np.array([False, True])
    )


# (stepper, the span over which it applies the start rate, in steps)
EARLY_CASES = {
    "tr": (nj.Trapezoidal(TIGHT), 0.5),
    "theta0.7": (nj.Theta(0.7, TIGHT), 0.3),
    "bathe": (nj.Bathe(solver=TIGHT), 0.25),  # its trapezoidal stage over h / 2
}


@pytest.mark.parametrize("name", list(EARLY_CASES))
def test_a_stage_crossing_a_switch_early_is_backward_euler(name):
    # A step across the switch that applies the old rate for a span s is off by
    # 2 (s - tau) (the theta method: s = (1 - theta) h; Bathe's trapezoidal first stage
    # over gamma h: s = gamma h / 2, its second stage restarting as backward Euler after
    # the switch); one whose stage is backward Euler's, by -2 tau (the new rate from the
    # start). A stage predicted to cross before s / 2 is backward Euler's, the nearer, and
    # the error of each step is the smaller of the two. Its estimate covers it; a theta
    # step taken as backward Euler's is backward Euler's step, estimate included.
    stepper, span = EARLY_CASES[name]
    model, h = _crossing_relay(), 0.1
    step = jax.jit(lambda y0: stepper.step(model, jnp.asarray(0.0), h, y0, None))
    backward = nj.BackwardEuler(TIGHT)
    be_step = jax.jit(lambda y0: backward.step(model, jnp.asarray(0.0), h, y0, None))
    for fraction in (0.05, 0.1, 0.2, 0.3):  # crossed by every stage (0.4: Bathe's lands)
        x0 = -3.0 * fraction * h
        out = step(jnp.array([x0, -1.0]))
        true = float(out.y1[0]) - (x0 + h + 2 * fraction * h)
        nearer = min(2 * fraction, abs(2 * (span - fraction))) * h
        np.testing.assert_allclose(abs(true), nearer, rtol=1e-9, atol=1e-15, err_msg=str(fraction))
        assert abs(float(out.y_error[0])) >= abs(true), (fraction, out.y_error, true)
        if fraction < span / 2 and name != "bathe":
            be = be_step(jnp.array([x0, -1.0]))
            np.testing.assert_allclose(out.y1, be.y1, rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(out.y_error, be.y_error, rtol=1e-12, atol=1e-15)


def test_theta_estimate_charges_a_face_reached_inside_the_step():
    # x' = v, v' = 3 with v held in [-1, 1] by a box on the differential row (a normal
    # cone: no multiplier, no reaction in f), from v0 = 1 - 3 tau: v reaches the face at
    # tau and stays, so x(h) = v0 tau + 3 tau^2 / 2 + (h - tau). The trapezoidal rule
    # averages v0 and 1 over the whole step: x off by (h - tau)(v0 - 1) / 2, which the
    # estimate of its smooth terms cannot see (the rates at both ends are the face's);
    # the switch's kink charge must cover it at every tau (with the kink's factor h - tau
    # taken as tau, the estimate was exactly 0 against a true 3.75e-3 at tau = h / 2).
    a, h = 3.0, 0.1
    model = Model.build(
        lambda t, y, args: jnp.stack([y[1], a + 0 * y[1]]),
        nj.BlockProjector([([1], nj.Box(-1.0, 1.0))]),
        None,
        np.zeros(2, bool),
    )
    step = jax.jit(lambda y0: nj.Trapezoidal(TIGHT).step(model, jnp.asarray(0.0), h, y0, None))
    for fraction in (0.1, 0.3, 0.5, 0.7, 0.9):
        tau = fraction * h
        v0 = 1.0 - a * tau
        out = step(jnp.array([0.0, v0]))
        assert float(out.y1[1]) == 1.0
        true = float(out.y1[0]) - (v0 * tau + a * tau**2 / 2 + (h - tau))
        np.testing.assert_allclose(true, 0.5 * (h - tau) * (v0 - 1.0), rtol=1e-9)
        assert abs(float(out.y_error[0])) >= abs(true), (fraction, out.y_error, true)


def test_theta_estimate_is_zero_inside_a_sliding_mode():
    # x' = -w + d(t), w in Sign(x), d = 0.3 + 0.5 t: from x = 0 the state slides, x = 0
    # exactly, with w = d(t) its equivalent control. A trapezoidal step inside the sliding
    # mode is exact in the state; its estimate must be too: the multiplier's secant rate
    # makes the flow's derivative -w' + d' vanish, as the true one does (a multiplier taken
    # as constant charged h^2 d' / 2 = 2.5e-3 at h = 0.1, shrinking steps for no error).
    # Backward Euler's start rate likewise: the smaller of f1 - f0 and f1 - f0_end, where
    # f0_end applies the end's equivalent control at t0 (off by h d': an estimate of
    # h^2 d' / 4 = 2.5e-3 at h = 0.1 with f0_end alone).
    scene = nj.Scene(
        lambda t, x, a, m: -m["w"] + 0.3 + 0.5 * t, 1, (nj.Relay("w", lambda t, x, a: x),)
    )
    model = Model.build(
        scene.vector_field, scene.projector, scene.full_mass_matrix, np.array([False, True])
    )
    for stepper in (nj.Trapezoidal(TIGHT), nj.BackwardEuler(TIGHT)):
        step = jax.jit(lambda t0, h, y0, s=stepper: s.step(model, t0, h, y0, None))
        for t0, h in ((0.0, 0.1), (0.7, 0.02)):
            out = step(jnp.asarray(t0), jnp.asarray(h), jnp.array([0.0, 0.3 + 0.5 * t0]))
            np.testing.assert_allclose(out.y1, [0.0, 0.3 + 0.5 * (t0 + h)], atol=1e-12)
            assert np.max(np.abs(np.asarray(out.y_error))) <= 1e-12, (stepper, t0, out.y_error)


def test_bathe_estimate_is_zero_for_a_body_held_under_a_varying_load():
    # x' = v, v' = 2 + 3 t with v held at the face v = 1 of a box (the load pushes out all
    # along): the motion x = x0 + t, v = 1 is exact for every scheme, and so must be the
    # estimate. The holding reaction r = -(2 + 3 t) varies in time; linear in time, it
    # drops out of the estimate's second divided difference (the holding force applied at
    # t1 alone counted as error: an estimate of 3.8e-2 at h = 0.1 for an exact step).
    model = Model.build(
        lambda t, y, args: jnp.stack([y[1], 2.0 + 3.0 * t + 0 * y[1]]),
        nj.BlockProjector([([1], nj.Box(-1.0, 1.0))]),
        None,
        np.zeros(2, bool),
    )
    step = jax.jit(
        lambda t0, h: nj.Bathe(solver=TIGHT).step(model, t0, h, jnp.array([0.0, 1.0]), None)
    )
    for t0, h in ((0.0, 0.1), (0.4, 0.3)):
        out = step(jnp.asarray(t0), jnp.asarray(h))
        np.testing.assert_allclose(out.y1, [h, 1.0], rtol=1e-13)
        assert np.max(np.abs(np.asarray(out.y_error))) <= 1e-13, (t0, h, out.y_error)


def test_bathe_estimate_charges_a_switch_inside_its_first_stage():
    # x' = -w + 2, w in Sign(x), from x0 = -3 tau: x' = 3 until x = 0 at tau, 1 after, so
    # x(h) = h - tau. With tau inside Bathe's first (trapezoidal) stage, the stage changes
    # face and the second restarts as backward Euler; the estimate of the two sub-steps
    # must charge the rate jump inside the first, gamma h (f_mid - f0) / 2, and cover the
    # true error at every tau (without it: an estimate of 0 against a true 0.04 at
    # tau = 0.05 h, both stages ending on the same branch).
    scene = nj.Scene(lambda t, x, a, m: -m["w"] + 2.0, 1, (nj.Relay("w", lambda t, x, a: x),))
    model = Model.build(
        scene.vector_field, scene.projector, scene.full_mass_matrix, np.array([False, True])
    )
    h = 0.1
    step = jax.jit(lambda y0: nj.Bathe(solver=TIGHT).step(model, jnp.asarray(0.0), h, y0, None))
    for fraction in (0.05, 0.15, 0.25, 0.35, 0.45):
        out = step(jnp.array([-3.0 * fraction * h, -1.0]))
        true = float(out.y1[0]) - (h - fraction * h)
        assert abs(float(out.y_error[0])) >= abs(true), (fraction, out.y_error, true)


def test_an_event_predicted_at_the_end_of_a_step_up_to_rounding_lies_inside_it():
    # A step landing on a switching surface predicts its event at the end, tau = h up to
    # the rounding of the secant (measured one ulp above h for a step jumping onto a
    # sliding set; left uncharged, a successful run's sliding time was off by 8e-4 at
    # rtol 1e-5). Such a tau counts as inside the step, as h; one clearly beyond it does
    # not, and one inside is kept.
    from nivpjax._stepper.one_leg import event_in_step

    class Predicts(eqx.Module):
        tau: jax.Array

        def next_event(self, t1, h, y0, y1, args, started=False):
            return self.tau

    h, y = jnp.asarray(0.1), jnp.zeros(1)
    eps = float(jnp.finfo(y.dtype).eps)
    for tau, inside in ((h * (1 + 4 * eps), h), (h * 1.01, 0.0), (0.5 * h, 0.5 * h)):
        got = event_in_step(Predicts(jnp.asarray(tau)), 0.0, h, y, y, None)
        assert float(got) == float(inside), (tau, got)


def _two_blocks():
    # x' = v, v' = F - c Sign(v) for two uncoupled blocks: A under F = 1 + t/2 with c = 3
    # (slides to rest), B under F = 2 + 3 t with c = 10 (held throughout).
    scene = nj.Scene(
        lambda t, x, a, m: jnp.stack([x[2], x[3], 1.0 + 0.5 * t, 2.0 + 3.0 * t]),
        4,
        (nj.Friction([2, 3], jnp.array([3.0, 10.0])),),
    )
    return Model.build(scene.vector_field, scene.projector, None, np.zeros(4, bool))


@pytest.mark.parametrize("stepper", ["bathe", "trapezoidal"])
def test_estimate_of_a_block_coming_to_rest_inside_the_step(stepper):
    # Block A starts at v0 = 2 tau - tau^2/4 and comes to rest at tau (closed form:
    # v = v0 - 2t + t^2/4, x(tau) = v0 tau - tau^2 + tau^3/12), inside the first stage or
    # the second. Its velocity at the end, zero, is exact, and so must be its estimate
    # (before: 5e-3 to 8.7e-2, the jump of its rate, at any step size: the fault's steps
    # collapsed at each cell's arrest). The arrest's timing is an error of x, which the
    # estimate keeps (ratio to the true error 0.62 to 9.7 over these positions of tau).
    # Block B is held throughout: its estimate is zero whichever block switched (before:
    # 3e-2 when A stopped in the first stage, the restart's estimate charging the change
    # of B's load, which its reaction cancels).
    # The trapezoidal rule likewise (before: its defect term charged the jump, 0.195 on
    # block A at tau = 0.1 h, and the work-precision slider took up to twice the steps of
    # the code before friction was weighed, at the same errors).
    h = 0.2
    scheme = {"bathe": nj.Bathe, "trapezoidal": nj.Trapezoidal}[stepper](solver=TIGHT)
    step = jax.jit(lambda y0: scheme.step(_two_blocks(), jnp.asarray(0.0), h, y0, None))
    for fraction in (0.1, 0.3, 0.45, 0.55, 0.7, 0.9):
        tau = fraction * h
        v0 = 2 * tau - 0.25 * tau**2
        out = step(jnp.array([0.0, 0.0, v0, 0.0]))
        y1, est = np.asarray(out.y1), np.asarray(out.y_error)
        assert np.all(np.abs(y1[2:]) < 1e-15), (fraction, y1)
        assert est[2] == 0.0 and np.all(np.abs(est[1::2]) < 1e-15), (fraction, est)
        true = y1[0] - (v0 * tau - tau**2 + tau**3 / 12)
        assert 0.6 * abs(true) <= abs(est[0]) <= 10 * abs(true), (fraction, est[0], true)


def test_arrest_error_is_the_slip_velocity_left_at_the_end():
    # A block under a load growing from 1 to 1 + h/2 against c = 3 from v0 = 1: along
    # its slip the acceleration is linear, -2 + t/2, so v0 + h (a0 + a1)/2 is its exact
    # velocity at h; it reaches zero at tau = 4 - 2 sqrt 3 = 0.536. A step stuck at the end
    # is exact beyond tau (error 0) and off by that velocity before it.
    projector = nj.BlockProjector([([1], nj.CoulombFriction(3.0))])

    def arrest(h, v1, v0=1.0):
        ctx = nj.ProjectionContext(
            t=jnp.asarray(h),
            h=jnp.asarray(h),
            y_prev=jnp.array([0.0, v0]),
            y_iter=jnp.array([0.1, v1]),
            rho=jnp.full(2, h),
            args=None,
            start_rate=jnp.array([v0, 1.0]),
            end_rate=jnp.array([v1, 1.0 + 0.5 * h]),
        )
        arrested, error = projector.arrest_error(ctx)
        return np.asarray(arrested), np.asarray(error)

    for h in (0.1, 0.3, 0.5):
        arrested, error = arrest(h, 0.0)
        np.testing.assert_array_equal(arrested, [False, True])
        np.testing.assert_allclose(error, [0.0, 1.0 - 2 * h + 0.25 * h**2], rtol=1e-14)
    for h in (0.6, 1.0):
        arrested, error = arrest(h, 0.0)
        np.testing.assert_array_equal(arrested, [False, True])
        np.testing.assert_array_equal(error, [0.0, 0.0])
    # Not an arrest: still sliding at the end, or stuck at both ends.
    for v0, v1 in ((1.0, 0.4), (0.0, 0.0)):
        arrested, error = arrest(0.3, v1, v0)
        assert not arrested.any() and not error.any(), (v0, v1)


# A rate with a square-root singularity just past the step, y' = sqrt(B - t) (the
# super-twisting term k1 sqrt|sigma| while sigma runs into 0): its Taylor series converges
# only within B - t, and a step of half that is ordinary for a controller approaching the
# crossing. The trapezoidal rule's error is its quadrature error there, in closed form.
# Its estimate h^2/12 (F1' - F0') tracks it; the defect term (1 - theta) h D, O(h^4) on a
# smooth piece, is there for jumps of the rate: added to it, it cancelled the estimate to
# 0.4 of the error at h = 0.58 (B - t0) (a super-twisting run at rtol 1e-4 accepted a step
# 4.7 times its tolerance before the first crossing, 14 times its estimate).
B = 1.0


def _sqrt_rate(t, y, args):
    return jnp.sqrt(B - t) * jnp.ones_like(y)


SQRT_MODEL = Model(
    vector_field=_sqrt_rate,
    projector=nj.Identity(),
    mass_matrix=None,
    algebraic=jnp.zeros(1, bool),
)


@pytest.mark.parametrize("name", ["tr", "theta0.7"])
def test_theta_estimate_near_a_square_root_singularity(name):
    stepper = CASES[name][0]
    theta = stepper.theta
    step = jax.jit(lambda t0, h: stepper.step(SQRT_MODEL, t0, h, jnp.zeros(1), None))
    for reach, fraction in ((0.121, 0.58), (0.2, 0.4), (0.1, 0.3)):
        t0, h = B - reach, fraction * reach
        out = step(jnp.asarray(t0), jnp.asarray(h))
        exact = 2 / 3 * (reach**1.5 - (reach - h) ** 1.5)
        true = float(out.y1[0]) - exact
        ratio = float(out.y_error[0]) / true
        assert 0.75 <= ratio <= 1.5, (name, theta, reach, fraction, ratio)
