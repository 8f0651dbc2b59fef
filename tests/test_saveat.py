"""`SaveAt`: each save mode gives the full save's final state and `t_eval` states, the
step buffers are not allocated in the loop when the steps are not saved, and gradients
through a final-only or times-only solve equal those through the full save."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj


T1 = 1.5
KW = dict(max_steps=61, controller=nj.PIDController(rtol=1e-4, atol=1e-6))


@pytest.fixture(scope="module")
def ball():
    scene, x0, args = nj.scenes.bouncing_ball()
    steps = scene.solve(0.0, T1, x0, args, **KW)
    k = int(steps.n_accepted)
    # Output times on a grid, at accepted step times (where an impact's step starts: the
    # step a time belongs to matters there) and at both ends.
    ts = np.asarray(steps.ts)[1:k]
    t_eval = np.unique(np.concatenate([np.linspace(0.0, T1, 23), ts, [T1]]))
    full = scene.solve(0.0, T1, x0, args, t_eval=t_eval, **KW)
    return scene, x0, args, steps, t_eval, full


def test_every_save_mode_matches_the_full_save(ball):
    scene, x0, args, steps, t_eval, full = ball
    assert int(steps.n_accepted) >= 4  # several impacts inside [0, T1]
    final = scene.solve(0.0, T1, x0, args, saveat=nj.SaveAt(), **KW)
    at_ts = scene.solve(0.0, T1, x0, args, saveat=nj.SaveAt(ts=t_eval), **KW)
    # `t_eval` with `SaveAt()` is the same as `SaveAt(ts=...)`: one compiled program.
    via_t_eval = scene.solve(0.0, T1, x0, args, t_eval=t_eval, saveat=nj.SaveAt(), **KW)
    for sol in (final, at_ts, via_t_eval):
        np.testing.assert_array_equal(sol.y_final, full.y_final)
        np.testing.assert_array_equal(sol.t_final, full.t_final)
        assert int(sol.n_accepted) == int(full.n_accepted)
        assert int(sol.n_rejected) == int(full.n_rejected)
        assert sol.result == nj.RESULTS.successful
    assert final.y_eval is None and final.t_eval is None
    for sol in (at_ts, via_t_eval):
        np.testing.assert_array_equal(sol.t_eval, full.t_eval)
        assert not np.isnan(sol.y_eval).any()
        # The same interpolant, evaluated in the loop instead of after it: equal up to
        # the round-off of a differently fused program.
        np.testing.assert_allclose(sol.y_eval, full.y_eval, rtol=0, atol=1e-13)


def test_steps_are_absent_without_saveat_steps(ball):
    scene, x0, args, _, t_eval, _ = ball
    rows = KW["max_steps"] + 1  # 62: no other array of the program has it as a dimension

    def program(saveat):
        f = lambda x: scene.solve(0.0, T1, x, args, saveat=saveat, throw=False, **KW)  # noqa: E731
        return str(jax.make_jaxpr(f)(jnp.asarray(x0)))

    has_rows = re.compile(rf"\[{rows}[,\]]")
    assert has_rows.search(program(nj.SaveAt(steps=True)))  # the buffers, when saved
    for saveat in (nj.SaveAt(), nj.SaveAt(ts=t_eval)):
        assert not has_rows.search(program(saveat)), saveat  # not allocated anywhere
    sol = scene.solve(0.0, T1, x0, args, saveat=nj.SaveAt(), **KW)
    steps = ("ts", "ys", "hs", "multipliers", "iterations", "residual_norms")
    assert all(getattr(sol, name) is None for name in steps + ("nonlinear_success",))
    assert sol.trimmed().ys is None


def test_times_given_twice_and_bad_saveat_raise():
    f = lambda t, y, args: -y  # noqa: E731
    with pytest.raises(ValueError, match="given twice"):
        nj.solve(f, 0.0, 1.0, jnp.ones(1), t_eval=[0.5], saveat=nj.SaveAt(ts=[0.5]))
    with pytest.raises(TypeError, match="saveat"):
        nj.solve(f, 0.0, 1.0, jnp.ones(1), saveat="final")
    with pytest.raises(TypeError, match="steps"):
        nj.SaveAt(steps=1)


def _oscillator(t, y, args):
    return jnp.array([y[1], -args["k"] * y[0] - 0.3 * y[1]])


def test_gradients_without_saved_steps_equal_the_full_save():
    # A smooth oscillator (cheap to compile in reverse mode): the checkpointed loop with
    # no step buffers, and with the states at t_eval filled in the loop, against the same
    # loop with every step saved and t_eval interpolated after it.
    t_eval = jnp.linspace(0.0, 2.0, 7)
    # Fixed steps, so that a finite difference sees the same step sequence.
    kw = dict(stepper=nj.Trapezoidal(), controller=nj.ConstantStepSize(), h0=0.05)
    kw.update(max_steps=64, throw=False)
    y0 = jnp.array([1.0, 0.0])

    def loss(k, saveat, te):
        sol = nj.solve(_oscillator, 0.0, 2.0, y0, {"k": k}, saveat=saveat, t_eval=te, **kw)
        out = sol.y_final[0] ** 2
        return out if te is None else out + jnp.sum(sol.y_eval[:, 0] * jnp.arange(7.0))

    grad = jax.grad(loss)
    k = jnp.asarray(2.0)
    full = grad(k, nj.SaveAt(steps=True), t_eval)
    # the two parts of the full loss, each from the full save
    full_final = grad(k, nj.SaveAt(steps=True), None)
    assert abs(float(full - full_final)) > 1e-2  # the t_eval part matters
    np.testing.assert_allclose(grad(k, nj.SaveAt(), None), full_final, rtol=1e-12)
    np.testing.assert_allclose(grad(k, nj.SaveAt(), t_eval), full, rtol=1e-12)
    # and a finite difference of the full save's loss (the gradient is a gradient)
    eps = 1e-6
    fd = (loss(k + eps, nj.SaveAt(), t_eval) - loss(k - eps, nj.SaveAt(), t_eval)) / (2 * eps)
    np.testing.assert_allclose(full, fd, rtol=1e-4)


def test_a_failed_run_leaves_nan_after_where_it_stopped():
    # 20 fixed steps of 0.05 reach t = 1 of [0, 2]: the states at the times before come
    # from the loop as from saved steps, the ones after are NaN (the result says why).
    kw = dict(stepper=nj.Trapezoidal(), controller=nj.ConstantStepSize(), h0=0.05)
    kw.update(max_steps=20, throw=False, t_eval=np.linspace(0.0, 2.0, 8))
    y0, args = jnp.array([1.0, 0.0]), {"k": 2.0}
    full = nj.solve(_oscillator, 0.0, 2.0, y0, args, **kw)
    loop = nj.solve(_oscillator, 0.0, 2.0, y0, args, saveat=nj.SaveAt(), **kw)
    assert loop.result == nj.RESULTS.time_max_steps_reached
    np.testing.assert_allclose(float(loop.t_final), 1.0, rtol=1e-12)
    before = np.asarray(loop.t_eval) < 1.0
    assert before.sum() == 4 and np.isfinite(loop.y_eval[before]).all()
    assert np.isnan(loop.y_eval[~before]).all() and np.isnan(full.y_eval[~before]).all()
    np.testing.assert_allclose(loop.y_eval[before], full.y_eval[before], rtol=0, atol=1e-13)
