"""`StepDoublingController`: the reference package's classic step-doubling controller.

Checked against the reference's own `AdaptiveStepping` (solve_nivp, installed as a peer)
driving the same backward Euler steps, and against the known local error of backward
Euler on $y' = \\lambda y$."""

import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj


solve_nivp = pytest.importorskip("solve_nivp.adaptive_integrator")

LAM = np.array([-1.0, -3.0])
Y0 = np.array([1.0, 2.0])
T1 = 2.0


def _field(t, y, args):
    return jnp.asarray(LAM) * y


class _ExactBackwardEuler:
    """Backward Euler on y' = lam y, solved exactly (the reference's integrator protocol)."""

    order = 1

    def step(self, fun, t, y, h):
        return y / (1.0 - LAM * h), None, 0.0, True, 1


def _reference_times(rtol, atol, h_up, use_pi):
    control = solve_nivp.AdaptiveStepping(
        _ExactBackwardEuler(),
        atol=atol,
        rtol=rtol,
        h0=1e-2,
        h_up=h_up,
        h_down=0.6,
        method_order=1,
        use_PI=use_pi,
    )
    t, y, h, times = 0.0, Y0.copy(), 1e-2, [0.0]
    while t < T1 - 1e-12:
        h = min(h, T1 - t)
        y_new, _, h_next, _, ok, *_ = control.step(None, t, y, h)
        if ok:
            t, y = t + h, y_new
            times.append(t)
        h = h_next
    return np.array(times), y


@pytest.mark.parametrize("rtol", [1e-3, 1e-5])
@pytest.mark.parametrize("use_pi", [True, False])
def test_same_steps_as_the_reference(rtol, use_pi):
    atol = rtol / 100
    ref_ts, ref_y = _reference_times(rtol, atol, 1.8, use_pi)
    control = nj.StepDoublingController(rtol=rtol, atol=atol, order=1, use_pi=use_pi)
    stepper = nj.BackwardEuler(solver=nj.SemismoothNewton(rtol=1e-13, atol=1e-15))
    sol = nj.solve(_field, 0.0, T1, jnp.asarray(Y0), stepper=stepper, controller=control)
    k = int(sol.n_accepted)
    ts = np.asarray(sol.ts[: k + 1])
    assert k == len(ref_ts) - 1
    np.testing.assert_allclose(ts, ref_ts, rtol=1e-8)
    np.testing.assert_allclose(np.asarray(sol.ys[k]), ref_y, rtol=1e-8)


def test_estimate_is_the_local_error_of_the_half_steps():
    # One attempt from y0: Richardson's (y_hi - y_lo)/(2^p - 1) against the exact local
    # error of the two half steps, y0 e^{lam h} - y_hi (Richardson's sign: exact minus
    # computed); they agree to O(h) relatively.
    model = nj.Model.build(_field, nj.Identity(), None, np.zeros(2, bool))
    stepper = nj.Richardson(nj.BackwardEuler(solver=nj.SemismoothNewton(rtol=1e-13, atol=1e-15)))
    for h in (1e-2, 1e-3):
        out = stepper.step(model, jnp.asarray(0.0), jnp.asarray(h), jnp.asarray(Y0), None)
        exact = Y0 * np.exp(LAM * h)
        true_error = exact - np.asarray(out.y1)
        np.testing.assert_allclose(np.asarray(out.y_error), true_error, rtol=5 * h * 3)


def test_decisions_on_hand_made_errors():
    # The rule itself: accept iff E <= 1, factor clip(0.9 E^-a E_prev^-b, 0.6, 1.8) after
    # a first proportional step, 0.6 on a rejection; p = 1: a = 0.35, b = 0.2.
    control = nj.StepDoublingController(rtol=1e-14, atol=1.0, order=1)
    stats = nj.StepStats(
        nonlinear_result=nj.RESULTS.successful,
        iterations=jnp.asarray(1, jnp.int32),
        residual_norm=jnp.asarray(0.0),
    )

    def info(err):
        # One component, y0 = y1 = 0, rtol ~ 0: the scale is atol = 1 and E = |y_error| (p = 1,
        # Richardson's divisor for a first-order stepper is 1).
        return nj.StepInfo(
            t0=jnp.asarray(0.0),
            h=jnp.asarray(1.0),
            t1=jnp.asarray(10.0),
            y0=jnp.zeros(1),
            y1=jnp.zeros(1),
            y_error=jnp.asarray([err]),
            error_order=2,
            stats=stats,
            error_mask=jnp.ones(1, bool),
            violation=jnp.asarray(0.0),
            next_event=jnp.asarray(jnp.inf),
        )

    _, state = control.init(0.0, 10.0, jnp.zeros(1), 1.0, jnp.zeros(1), 2, jnp.ones(1, bool))
    accept, h, state = control.adapt(info(0.5), state)
    assert bool(accept) and np.isclose(h, 0.9 * 0.5**-0.5)
    accept, h, state = control.adapt(info(2.0), state)
    assert not bool(accept) and np.isclose(h, 0.6)
    accept, h, state = control.adapt(info(0.8), state)
    assert bool(accept) and np.isclose(h, 0.9 * 0.8**-0.35 * 0.5**-0.2)
    accept, h, state = control.adapt(info(1e-6), state)
    assert bool(accept) and np.isclose(h, 1.8)
    accept, h, state = control.adapt(info(0.0), state)
    assert bool(accept) and np.isclose(h, 1.8)


def test_embedded_estimate_refused():
    with pytest.raises(ValueError, match="step doubling"):
        nj.solve(
            _field,
            0.0,
            1.0,
            jnp.asarray(Y0),
            stepper=nj.Bathe(),
            controller=nj.StepDoublingController(),
            error_estimate="embedded",
        )


def test_bad_factors_refused():
    with pytest.raises(ValueError, match="factormin"):
        nj.StepDoublingController(factormin=1.2)
