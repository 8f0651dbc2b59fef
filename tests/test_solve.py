"""Time stepping: orders, adaptive accuracy, DAEs, vmap, gradients, outputs, failures."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj


def oscillator(t, y, args):
    return jnp.stack([y[1], -args * y[0]])


def exact_oscillator(t, k=1.0):
    w = np.sqrt(k)
    return np.array([np.cos(w * t), -w * np.sin(w * t)])


Y0 = jnp.array([1.0, 0.0])

STEPPERS = {
    "backward_euler": (nj.BackwardEuler(), 1),
    "trapezoidal": (nj.Trapezoidal(), 2),
    "theta_0.7": (nj.Theta(0.7), 1),
    "bathe": (nj.Bathe(), 2),
    "bathe_gamma_0.4": (nj.Bathe(gamma=0.4), 2),
    "embedded_be": (nj.EmbeddedBETR(), 1),
    "embedded_tr": (nj.EmbeddedBETR(propagate="trapezoidal"), 2),
}


def _fixed_final(stepper):
    @jax.jit
    def run(h):
        sol = nj.solve(
            oscillator,
            0.0,
            1.0,
            Y0,
            1.0,
            stepper=stepper,
            controller=nj.ConstantStepSize(),
            h0=h,
            max_steps=128,
        )
        return sol.y_final, sol.result

    return run


@pytest.mark.parametrize("name", STEPPERS)
def test_order_of_convergence(name):
    stepper, order = STEPPERS[name]
    run = _fixed_final(stepper)
    hs = np.array([1 / 8, 1 / 16, 1 / 32, 1 / 64])
    errors = []
    for h in hs:
        y, result = run(h)
        assert result == nj.RESULTS.successful
        errors.append(np.max(np.abs(np.asarray(y) - exact_oscillator(1.0))))
    slope = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    assert abs(slope - order) < 0.15, (slope, errors)


@pytest.mark.parametrize("name", ["backward_euler", "bathe", "embedded_tr"])
def test_adaptive_meets_tolerance(name):
    stepper, order = STEPPERS[name]
    errs = []
    for rtol in (1e-4, 1e-6):
        ctrl = nj.PIDController(rtol=rtol, atol=rtol * 1e-2)
        sol = nj.solve(
            oscillator, 0.0, 2.0, Y0, 1.0, stepper=stepper, controller=ctrl, max_steps=20000
        )
        assert sol.result == nj.RESULTS.successful
        err = np.max(np.abs(np.asarray(sol.y_final) - exact_oscillator(2.0)))
        errs.append(err)
        # Error-per-step control: the global error is at most the sum of the accepted local
        # errors (<= rtol-scaled each) for a first-order scheme; a second-order scheme's
        # estimate is conservative and its global error stays within a modest multiple.
        bound = 50 * rtol if order == 2 else 2 * rtol * float(sol.n_accepted)
        assert err < bound, (err, bound, int(sol.n_accepted))
    assert errs[1] < errs[0]


def test_dae_mass_matrix():
    """Index-1 DAE: x' = -x + z, 0 = z - 2x (so x' = x, x = e^t), with a non-identity
    differential block A = diag(2, 0) and x' scaled accordingly."""

    def f(t, y, args):
        x, z = y
        return jnp.stack([2.0 * (-x + z), z - 2.0 * x])

    A = jnp.diag(jnp.array([2.0, 0.0]))
    sol = nj.solve(
        f,
        0.0,
        1.0,
        jnp.array([1.0, 2.0]),
        mass_matrix=A,
        stepper=nj.Bathe(),
        controller=nj.PIDController(rtol=1e-8, atol=1e-10),
    )
    assert sol.result == nj.RESULTS.successful
    x, z = np.asarray(sol.y_final)
    # Error-per-step control: each accepted local error is at most atol + rtol |x| (Bathe's
    # embedded estimate is asymptotically exact: measured 0.97 / 0.98 / 0.99 of the true
    # local error of x' = x at h = 0.1 / 0.05 / 0.025), and x' = x amplifies it by at most
    # e up to t = 1, so |x(1) - e| <= n (atol + rtol e) e; 2x that, as in
    # test_adaptive_meets_tolerance. Measured 3.6e-6 (1.3e-6 relative) in 179 steps, bound
    # 2.7e-5 (the former rtol = 1e-6 relative bound assumed fewer than ~100 steps, as the
    # Richardson estimate took).
    n = float(sol.n_accepted)
    assert abs(x - np.e) <= 2 * n * (1e-10 + 1e-8 * np.e) * np.e, (x - np.e, n)
    assert abs(z - 2 * x) <= 1e-12 * abs(z)  # the algebraic row, to round-off


def test_unit_mass_matrix_masks_as_the_general_path_solves():
    """A = diag(1, 0) takes the masked path (`Model.unit_mass`), A = diag(2, 0) with the
    differential row scaled by 2 the general one (products and solves with A): the same
    DAE, so the same steps and the same solution to round-off."""

    def field(scale):
        return lambda t, y, args: jnp.stack([scale * (-y[0] + y[1]), y[1] - 2.0 * y[0]])

    runs = [
        nj.solve(
            field(scale),
            0.0,
            1.0,
            jnp.array([1.0, 2.0]),
            mass_matrix=np.diag([scale, 0.0]),
            controller=nj.PIDController(rtol=1e-6, atol=1e-9),
        )
        for scale in (1.0, 2.0)
    ]
    assert [int(r.n_accepted) for r in runs] == [int(runs[0].n_accepted)] * 2
    np.testing.assert_allclose(runs[0].y_final, runs[1].y_final, rtol=1e-12)
    np.testing.assert_allclose(runs[0].y_final[0], np.e, rtol=1e-4)


def test_vmap_equals_loop():
    ctrl = nj.PIDController(rtol=1e-6, atol=1e-8)
    run = jax.jit(
        lambda k, y0: nj.solve(oscillator, 0.0, 1.0, y0, k, controller=ctrl, max_steps=256)
    )
    ks = jnp.array([0.5, 1.0, 2.0, 4.0])
    y0s = jnp.stack([Y0, 2 * Y0, Y0 + 0.1, -Y0])
    batched = jax.vmap(run)(ks, y0s)
    for i in range(len(ks)):
        single = run(ks[i], y0s[i])
        assert int(batched.n_accepted[i]) == int(single.n_accepted)
        np.testing.assert_allclose(batched.y_final[i], single.y_final, rtol=1e-12, atol=1e-14)


def _fd(f, x, eps):
    return (f(x + eps) - f(x - eps)) / (2 * eps)


def test_gradient_smooth_adaptive():
    ctrl = nj.PIDController(rtol=1e-9, atol=1e-11)

    def loss(args, y0):
        sol = nj.solve(oscillator, 0.0, 1.0, y0, args, controller=ctrl, max_steps=1024)
        return sol.y_final[0] + 0.5 * sol.y_final[1]

    g_k, g_y0 = jax.jit(jax.grad(loss, argnums=(0, 1)))(2.0, Y0)
    w = np.sqrt(2.0)
    # y(1) = cos(w) y0 + sin(w)/w v0 ; v(1) = -w sin(w) y0 + cos(w) v0
    exact_y0 = [np.cos(w) - 0.5 * w * np.sin(w), np.sin(w) / w + 0.5 * np.cos(w)]
    np.testing.assert_allclose(g_y0, exact_y0, rtol=1e-6)
    f = jax.jit(lambda k: loss(k, Y0))
    np.testing.assert_allclose(g_k, _fd(f, 2.0, 1e-3), rtol=1e-5)


G = 9.81
BALL = nj.UnilateralContact(
    gap=lambda t, y, a: y[:1],
    velocity_map=lambda t, y, a: jnp.array([[0.0, 1.0]]),
    restitution=lambda t, y, a: a,
)


def ball_field(t, y, e):
    return jnp.stack([y[1], -G * jnp.ones_like(y[0])])


@pytest.mark.parametrize("stepper", [nj.BackwardEuler(), nj.Bathe()], ids=["be", "bathe"])
def test_gradient_through_impacts_fixed_step(stepper):
    """Reverse-mode gradient of the height after a bounce with respect to restitution, on a
    fixed mesh (the discrete map is smooth in e there), against central differences."""

    def loss(e):
        sol = nj.solve(
            ball_field,
            0.0,
            1.0,
            jnp.array([1.0, 0.0]),
            e,
            projector=BALL,
            stepper=stepper,
            controller=nj.ConstantStepSize(),
            h0=1 / 200,
            max_steps=256,
        )
        return sol.y_final[0]

    g = jax.jit(jax.grad(loss))(0.8)
    fd = _fd(jax.jit(loss), 0.8, 1e-5)
    np.testing.assert_allclose(g, fd, rtol=1e-6)
    # And it has the physical sign and size: d height / d e = v_impact * (t - t_impact) > 0.
    t_imp = np.sqrt(2 / G)
    assert g == pytest.approx(np.sqrt(2 * G) * (1 - t_imp), rel=0.05)


def test_gradient_through_friction_fixed_step():
    """Spring-slider with Coulomb friction: gradient of the position at t=1 with respect to
    the friction bound (sliding throughout), against central differences."""

    def f(t, y, args):
        v, x = y
        return jnp.stack([-x, v])

    def loss(c):
        proj = nj.BlockProjector([([0], nj.CoulombFriction(lambda t, y, a: a))])
        sol = nj.solve(
            f,
            0.0,
            1.0,
            jnp.array([2.0, 0.0]),
            c,
            projector=proj,
            stepper=nj.Bathe(),
            controller=nj.ConstantStepSize(),
            h0=1 / 100,
            max_steps=128,
        )
        return sol.y_final[1]

    g = jax.jit(jax.grad(loss))(0.3)
    fd = _fd(jax.jit(loss), 0.3, 1e-5)
    np.testing.assert_allclose(g, fd, rtol=1e-6)
    # Exact (sliding with v > 0): x'' = -x - c, x(1) = (2 sin 1) - c (1 - cos 1).
    assert g == pytest.approx(-(1 - np.cos(1.0)), rel=1e-3)


def test_t_eval_and_buffers():
    ctrl = nj.PIDController(rtol=1e-8, atol=1e-10)
    t_eval = jnp.linspace(0.0, 1.0, 11)
    sol = nj.solve(oscillator, 0.0, 1.0, Y0, 1.0, controller=ctrl, t_eval=t_eval)
    exact = np.stack([exact_oscillator(t) for t in np.asarray(t_eval)])
    # Piecewise-linear interpolation between accepted steps: O(h^2) between mesh points.
    h_max = float(np.max(np.diff(np.asarray(sol.trimmed().ts))))
    np.testing.assert_allclose(sol.y_eval, exact, atol=h_max**2)
    trimmed = sol.trimmed()
    k = int(sol.n_accepted)
    assert trimmed.ts.shape == (k + 1,) and trimmed.ts[0] == 0.0 and trimmed.ts[-1] == 1.0
    np.testing.assert_allclose(np.diff(trimmed.ts), trimmed.hs[1:], rtol=1e-12)
    assert np.all(np.isfinite(sol.ys)) and np.all(np.isinf(sol.ts[k + 1 :]))


def test_attempt_log():
    sol = nj.solve(
        oscillator,
        0.0,
        1.0,
        Y0,
        1.0,
        save_attempts=True,
        h0=0.5,
        controller=nj.PIDController(rtol=1e-6, atol=1e-8),
    )
    n = int(sol.n_accepted + sol.n_rejected)
    log = sol.attempts
    assert int(np.sum(log.accepted[:n])) == int(sol.n_accepted)
    assert int(sol.n_rejected) >= 1  # h0 = 0.5 is far too large for rtol = 1e-6
    assert not bool(log.accepted[0])
    assert np.all(np.isinf(log.t[n:]))


def test_max_steps_reported_and_raised():
    kwargs = dict(controller=nj.PIDController(rtol=1e-8, atol=1e-10), max_steps=5)
    sol = nj.solve(oscillator, 0.0, 1.0, Y0, 1.0, throw=False, **kwargs)
    assert sol.result == nj.RESULTS.time_max_steps_reached
    assert float(sol.t_final) < 1.0
    with pytest.raises(nj.SolveError, match="failed at t = .*maximum number of time steps"):
        nj.solve(oscillator, 0.0, 1.0, Y0, 1.0, **kwargs)
    with pytest.raises(Exception, match="maximum number of time steps"):
        jax.jit(lambda y0: nj.solve(oscillator, 0.0, 1.0, y0, 1.0, **kwargs).y_final)(Y0)


def test_result_prints_its_message():
    # `successful` was inherited from optimistix with an empty message: `RESULTS<>`.
    kwargs = dict(controller=nj.PIDController(rtol=1e-8, atol=1e-10), max_steps=5, throw=False)
    ok = nj.solve(oscillator, 0.0, 1e-3, Y0, 1.0, **kwargs)
    bad = nj.solve(oscillator, 0.0, 1.0, Y0, 1.0, **kwargs)
    assert ok.result == nj.RESULTS.successful
    assert str(ok.result) == repr(ok.result) == "nivpjax.RESULTS<successful>"
    assert nj.RESULTS[ok.result] == "successful"
    assert str(bad.result) == f"nivpjax.RESULTS<{nj.RESULTS[bad.result]}>"
    assert "Increase `max_steps`" in str(bad.result)


def test_h_min_reported():
    # A discontinuous right-hand side with a tolerance the floor on h cannot meet.
    f = lambda t, y, a: jnp.where(t < 0.5, 0.0, 1e6 * t) * jnp.ones_like(y)
    ctrl = nj.PIDController(rtol=1e-10, atol=1e-12, h_min=1e-3)
    sol = nj.solve(
        f, 0.0, 1.0, jnp.array([0.0]), controller=ctrl, throw=False, stepper=nj.BackwardEuler()
    )
    assert sol.result == nj.RESULTS.h_min_reached
    assert 0.49 < float(sol.t_final) <= 0.5


def test_vmap_failure_is_per_member():
    run = jax.vmap(
        lambda n_max, k: nj.solve(
            oscillator,
            0.0,
            1.0,
            Y0,
            k,
            max_steps=64,
            throw=False,
            controller=nj.PIDController(rtol=n_max, atol=1e-12),
        )
    )
    sol = run(jnp.array([1e-3, 1e-12, 1e-3]), jnp.array([1.0, 1.0, 2.0]))
    codes = [sol.result._value[i] for i in range(3)]
    assert codes[0] == nj.RESULTS.successful._value
    assert codes[1] == nj.RESULTS.time_max_steps_reached._value
    assert codes[2] == nj.RESULTS.successful._value
    np.testing.assert_allclose(sol.y_final[0], exact_oscillator(1.0), atol=1e-2)


def test_progress_meter(capfd):
    nj.solve(oscillator, 0.0, 1.0, Y0, 1.0, progress=True)
    assert "100.0%" in capfd.readouterr().err


def test_float32():
    y0 = jnp.array([1.0, 0.0], jnp.float32)
    sol = nj.solve(
        oscillator,
        0.0,
        1.0,
        y0,
        jnp.float32(1.0),
        controller=nj.PIDController(rtol=1e-4, atol=1e-6),
    )
    assert sol.ys.dtype == jnp.float32
    assert sol.result == nj.RESULTS.successful
    np.testing.assert_allclose(sol.y_final, exact_oscillator(1.0), atol=1e-3)


@pytest.mark.parametrize("h0", [0.1, 0.3, 1 / 7])
def test_fixed_steps_land_on_t1_without_a_round_off_step(h0):
    # Float accumulation of fixed steps leaves t a few ulps short of t1 (9 x 0.1 is
    # 0.8999999999999999); the step that would leave such a remainder lands on t1 instead.
    sol = nj.solve(
        lambda t, y, args: jnp.ones_like(y),
        0.0,
        1.0,
        jnp.zeros(1),
        stepper=nj.BackwardEuler(),
        controller=nj.ConstantStepSize(),
        h0=h0,
    )
    n = int(np.ceil(1.0 / h0 - 1e-9))
    assert int(sol.n_accepted) == n
    assert float(sol.ts[n]) == 1.0
    assert np.all(np.diff(np.asarray(sol.ts[: n + 1])) > 0.5 * min(h0, 1 - (n - 1) * h0))
