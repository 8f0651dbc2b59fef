"""PIDController against diffrax's; PolicyController: the PID-equivalent policy reproduces
PID; jit, vmap and grad."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nv
from nivpjax import scenes


STEPPER = nv.EmbeddedBETR()
ORDER = STEPPER.error_order
TOL = dict(rtol=1e-4, atol=1e-7)


def _ball(controller, args, t1=1.2, **kw):
    scene, x0, _ = scenes.bouncing_ball(restitution=0.7)
    return scene.solve(
        0.0, t1, x0, args, stepper=STEPPER, controller=controller, max_steps=800, **kw
    )


@eqx.filter_jit
def _ball_jit(controller, args, t1):
    return _ball(controller, args, t1, throw=False)


def _args(e=0.7):
    return {"e": jnp.asarray(e), "g": jnp.asarray(9.81)}


def _unit_step_info(y_error, order):
    """A successful step of size 1 from t = 0 (t1 = 10) at y = 0, one component: with
    atol = 1 the scaled error is `y_error` itself."""
    zero = jnp.zeros(1)
    return nv.StepInfo(
        t0=jnp.array(0.0),
        h=jnp.array(1.0),
        t1=jnp.array(10.0),
        y0=zero,
        y1=zero,
        y_error=y_error,
        error_order=order,
        stats=nv.StepStats(jnp.array(1), jnp.array(0.0), nv.RESULTS.successful),
        error_mask=jnp.ones(1, bool),
        violation=jnp.array(0.0),
        next_event=jnp.array(jnp.inf),
    )


def test_pid_factors_match_diffrax_with_derivative_gain():
    # The same recorded error sequence through both controllers, with all three gains
    # nonzero: every step-size factor agrees with diffrax's PIDController. The sequence
    # keeps every step accepted with a factor inside (1, factormax), where the two agree by
    # design (diffrax never shrinks an accepted step; ours may, and does not grow right
    # after a rejection).
    import diffrax

    gains = dict(pcoeff=0.3, icoeff=0.4, dcoeff=0.2, factormax=100.0)
    ours = nv.PIDController(rtol=1e-3, atol=1.0, event_prediction=False, **gains)
    theirs = diffrax.PIDController(rtol=1e-3, atol=1.0, **gains)
    order = 3
    zero = jnp.zeros(1)  # y = 0: the scaled error is the error itself (atol = 1)
    state_ours = (jnp.array(1.0), jnp.array(1.0), jnp.array(False))
    state_theirs = (jnp.array(1.0), jnp.array(1.0), jnp.array(False))
    adapt_ours = jax.jit(lambda info, state: ours.adapt(info, state))
    adapt_theirs = jax.jit(
        lambda e, state: theirs.adapt_step_size(0.0, 1.0, zero, zero, None, e, order, state)
    )
    for error in [0.5, 0.05, 0.02, 1e-3, 8e-4, 1e-4, 6e-5, 1e-6]:
        y_error = jnp.array([error])
        info = _unit_step_info(y_error, order)
        accept, factor, state_ours = adapt_ours(info, state_ours)
        keep, t0, t1, _, state_theirs, _ = adapt_theirs(y_error, state_theirs)
        assert bool(accept) and bool(keep)
        assert 1.0 < float(factor) < 100.0, (error, factor)
        np.testing.assert_allclose(factor, t1 - t0, rtol=1e-13, err_msg=str(error))


def test_integral_policy_reproduces_pid():
    pid = _ball_jit(nv.PIDController(**TOL), _args(), 1.2)
    pol = _ball_jit(nv.PolicyController(nv.IntegralPolicy(ORDER), **TOL), _args(), 1.2)
    assert pid.result == nv.RESULTS.successful
    assert int(pid.n_rejected) > 0  # the rails (no growth after a rejection) are exercised
    assert int(pol.n_accepted) == int(pid.n_accepted)
    assert int(pol.n_rejected) == int(pid.n_rejected)
    k = int(pid.n_accepted) + 1
    np.testing.assert_allclose(pol.ts[:k], pid.ts[:k], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(pol.ys[:k], pid.ys[:k], rtol=1e-10, atol=1e-12)


def test_smooth_problem_reproduces_pid():
    def f(t, y, args):
        return jnp.stack([y[1], -args * y[0]])

    y0 = jnp.array([1.0, 0.0])
    pid = nv.solve(f, 0.0, 3.0, y0, 4.0, controller=nv.PIDController(**TOL), stepper=STEPPER)
    pol = nv.solve(
        f,
        0.0,
        3.0,
        y0,
        4.0,
        controller=nv.PolicyController(nv.IntegralPolicy(ORDER), **TOL),
        stepper=STEPPER,
    )
    k = int(pid.n_accepted) + 1
    assert int(pol.n_accepted) + 1 == k
    np.testing.assert_allclose(pol.ts[:k], pid.ts[:k], rtol=1e-12)


def _mlp_controller(seed=0):
    size = nv.StepFeatures().size
    mlp = eqx.nn.MLP(size, 1, 8, 1, key=jax.random.PRNGKey(seed))
    return nv.PolicyController(mlp, **TOL)


def test_features_finite_when_h_zero():
    feats = nv.StepFeatures()
    memory = feats.init(0.0, 1.0, jnp.float64)
    stats = nv.StepStats(jnp.array(0), jnp.array(0.0), nv.RESULTS.successful)
    info = nv.StepInfo(
        t0=jnp.array(1.0),
        h=jnp.array(0.0),
        t1=jnp.array(1.0),
        y0=jnp.zeros(2),
        y1=jnp.array([jnp.nan, jnp.inf]),
        y_error=jnp.zeros(2),
        error_order=2,
        stats=stats,
        error_mask=jnp.ones(2, bool),
        violation=jnp.array(0.0),
        next_event=jnp.array(jnp.inf),
    )

    def total(h):
        info2 = eqx.tree_at(lambda i: i.h, info, h)
        return jnp.sum(feats(info2, jnp.array(0.0), memory))

    phi = feats(info, jnp.array(jnp.inf), memory)
    assert phi.shape == (feats.size,)
    assert np.all(np.isfinite(phi))
    assert np.isfinite(jax.grad(total)(jnp.array(0.0)))


def test_jit_vmap_grad_with_early_finishers():
    controller = _mlp_controller()
    # Members end at different times: the short ones keep running the body with h = 0.
    t1s = jnp.array([0.3, 0.8, 1.2])
    es = jnp.array([0.6, 0.7, 0.8])

    def loss(e, t1):
        sol = _ball(controller, {"e": e, "g": jnp.asarray(9.81)}, t1, throw=False)
        return sol.y_final[0] + sol.y_final[1] ** 2

    values, grads = jax.jit(jax.vmap(jax.value_and_grad(loss)))(es, t1s)
    single = [float(jax.jit(loss)(e, t)) for e, t in zip(es, t1s)]
    np.testing.assert_allclose(values, single, rtol=1e-10)
    assert np.all(np.isfinite(grads))
    # Before the first impact (t ~ 0.45) the state does not depend on e.
    assert float(grads[0]) == 0.0
    # After bounces it does: compare with central differences at a moderate step
    # (the accepted mesh is piecewise constant in e).
    eps = 1e-4
    fd = (jax.jit(loss)(es[2] + eps, t1s[2]) - jax.jit(loss)(es[2] - eps, t1s[2])) / (2 * eps)
    np.testing.assert_allclose(grads[2], fd, rtol=0.05)


def test_policy_accepts_option_and_pathwise_gradient():
    size = nv.StepFeatures().size
    mlp = eqx.nn.MLP(size, 2, 8, 1, key=jax.random.PRNGKey(1))
    controller = nv.PolicyController(mlp, policy_accepts=True, differentiable_factor=True, **TOL)
    params, static = eqx.partition(controller, eqx.is_inexact_array)

    def loss(p):
        c = eqx.combine(p, static)
        sol = _ball(c, _args(), 0.3, throw=False)
        return sol.y_final[0]

    value, grads = jax.jit(jax.value_and_grad(loss))(params)
    assert np.isfinite(float(value))
    leaves = jax.tree.leaves(grads)
    assert all(np.all(np.isfinite(g)) for g in leaves)


def test_bad_input():
    with pytest.raises(TypeError, match="policy"):
        nv.PolicyController(3.0)
    with pytest.raises(ValueError, match="factormin"):
        nv.PolicyController(nv.IntegralPolicy(2), factormin=2.0)
    with pytest.raises(TypeError, match="features"):
        nv.PolicyController(nv.IntegralPolicy(2), features="x")


def test_pid_error_order_overrides_the_steppers():
    # `error_order` given to the controller replaces the stepper's (info.error_order) in the
    # exponents: its factors are diffrax's with that order, not with the stepper's.
    import diffrax

    ours = nv.PIDController(rtol=1e-3, atol=1.0, event_prediction=False, error_order=2)
    theirs = diffrax.PIDController(rtol=1e-3, atol=1.0)
    zero = jnp.zeros(1)
    state = (jnp.array(1.0), jnp.array(1.0), jnp.array(False))
    error = jnp.array([1e-3])
    info = _unit_step_info(error, 3)
    _, factor, _ = ours.adapt(info, state)
    _, t0, t1, *_ = theirs.adapt_step_size(0.0, 1.0, zero, zero, None, error, 2, state)
    np.testing.assert_allclose(factor, t1 - t0, rtol=1e-13)
    # And a failed nonlinear solve is rejected and shrinks by `nonlinear_factor`, whatever
    # its error estimate says.
    failed = nv.StepStats(jnp.array(50), jnp.array(1.0), nv.RESULTS.nonlinear_max_steps_reached)
    for e in (1e-8, 1e-3, 10.0):
        info = eqx.tree_at(lambda i: (i.stats, i.y_error), info, (failed, jnp.array([e])))
        accept, factor, _ = ours.adapt(info, state)
        assert not bool(accept)
        assert float(factor) == ours.nonlinear_factor


def test_masked_error_norm_is_the_rms_over_the_unmasked_rows():
    from nivpjax._norms import scaled_rms_norm

    e, y0, y1 = jnp.array([3e-4, 1.0, -2e-4, 5.0]), jnp.ones(4), jnp.full(4, 2.0)
    mask = jnp.array([True, False, True, False])
    rows = np.flatnonzero(mask)
    masked = scaled_rms_norm(e, y0, y1, 1e-3, 1e-6, mask)
    alone = scaled_rms_norm(e[rows], y0[rows], y1[rows], 1e-3, 1e-6)
    np.testing.assert_allclose(masked, alone, rtol=1e-15)
    assert float(scaled_rms_norm(e, y0, y1, 1e-3, 1e-6, jnp.zeros(4, bool))) == 0.0


def test_pid_first_step_is_hairer_wanners_guess_capped_at_a_tenth_of_the_interval():
    # Hairer & Wanner's first guess h0 = 0.01 |y0|_sc / |f0|_sc (1e-6 where either norm is
    # below 1e-5), never more than a tenth of [t0, t1]: a slow start (a state at rest, a
    # tiny slope) must not take the whole interval in one step. Reference in numpy.
    rtol, atol = 1e-3, 1e-6
    pid = nv.PIDController(rtol=rtol, atol=atol)
    y0 = jnp.array([1.0, -2.0])

    def reference(f0, t1):
        sc = atol + rtol * np.abs(np.asarray(y0))
        d0, d1 = (float(np.sqrt(np.mean((np.asarray(v) / sc) ** 2))) for v in (y0, f0))
        h = 1e-6 if min(d0, d1) < 1e-5 else 0.01 * d0 / d1
        return min(h, 0.1 * t1)

    cases = [(jnp.array([1e-3, 2e-3]), 1.0), (jnp.array([1e-3, 2e-3]), 200.0)]
    cases += [(jnp.array([30.0, -50.0]), 1.0)]
    for f0, t1 in cases:
        h, _ = pid.init(0.0, t1, y0, None, f0, 2, jnp.ones(2, bool))
        np.testing.assert_allclose(float(h), reference(f0, t1), rtol=1e-12)
    # The first case is the cap's: the guess alone would be 10, ten times the interval.
    assert reference(cases[0][0], 1e9) > 1.0


def test_a_rejected_attempt_is_retried_shorter():
    # After a rejection, an attempt that crossed the predicted event before its last
    # EVENT_SKIP is retried up to just before it, whatever the error-controlled proposal
    # (that judged the whole attempt, crossing included); one whose event lies in its
    # last EVENT_SKIP (it ended on the surface, up to the solver's tolerance) gets the
    # error-controlled proposal: retrying up to the event would repeat the same attempt,
    # rejected for the same error (measured: 7936 rejections of one step).
    from nivpjax._controller.events import EVENT_SKIP, land_before_event

    margin, proposal = 1e-2, jnp.asarray(0.5)  # the attempt has h = 1 (from t0 = 0)
    info = _unit_step_info(jnp.array([1.0]), 3)
    cases = [(0.3, 0.3 * (1 - margin)), (0.8, 0.8 * (1 - margin)), (1 - 0.5 * EVENT_SKIP, 0.5)]
    for event, expected in cases:
        at = eqx.tree_at(lambda i: i.next_event, info, jnp.asarray(event))
        h = land_before_event(at, jnp.asarray(False), jnp.asarray(True), proposal, margin)
        np.testing.assert_allclose(float(h), expected, rtol=1e-14)
