"""The drop-in as a reference user meets it: models written with NumPy (run on the host),
float64 whatever JAX's x64 mode, and plot-ready output at `t_eval`."""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_compat import G, ball_exact, ball_opts

import nivpjax as nj
from nivpjax.compat import ModelError, NumpyModelWarning, _host, solve_ivp_ns


BALL = dict(
    method="composite",
    projection="unilateral",
    solver="semismooth_newton",
    solver_opts=dict(tol=1e-12, max_iter=50),
    atol=1e-8,
    rtol=1e-6,
    h0=1e-3,
)


def ball(xp, **kwargs):
    """The reference's ball, y = (v, s), with `fun` and the contact maps written in `xp`."""
    return solve_ivp_ns(
        lambda t, y: xp.array([-G, y[0]]),
        (0.0, 3.0),
        np.array([1.0, 2.0]),
        projection_opts=ball_opts(xp),
        **BALL,
        **kwargs,
    )


def relay(xp):
    """x' = -w + d(t), w in Sign(x): reaches x = 0 and slides (see test_compat)."""
    return solve_ivp_ns(
        lambda t, y: xp.array([-y[1] + 0.5 * xp.sin(2 * xp.pi * t), 0.0]),
        (0.0, 2.0),
        np.array([0.5, 1.0]),
        method="composite",
        projection="sign",
        solver="semismooth_newton",
        projection_opts=dict(y_indices=[0], w_indices=[1]),
        solver_opts=dict(tol=1e-12, max_iter=100),
        adaptive_opts=dict(h_max=0.05, skip_error_indices=[1]),
        atol=1e-8,
        rtol=1e-6,
        component_slices=[slice(0, 1), slice(1, 2)],
        A=np.diag([1.0, 0.0]),
    )


def _numpy_warnings(call):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = call()
    return out, [w for w in caught if issubclass(w.category, NumpyModelWarning)]


@pytest.mark.parametrize("model", [ball, relay])
def test_numpy_model_takes_the_steps_of_its_jax_numpy_twin(model, monkeypatch):
    """A NumPy model runs on the host with finite-difference Jacobians: the same steps as
    the same model in jax.numpy, values to round-off of the differences; one warning per
    model, naming its category and jax.numpy."""
    monkeypatch.setattr(_host, "_WARNED", set())
    t_j, y_j, h_j, fk_j, info_j = model(jnp)
    (t_n, y_n, h_n, fk_n, info_n), first = _numpy_warnings(lambda: model(np))
    _, again = _numpy_warnings(lambda: model(np))
    assert len(first) == 1 and not again
    message = str(first[0].message)
    assert "`fun`" in message and "jax.numpy" in message and "NumpyModelWarning" in message
    assert t_n.shape == t_j.shape
    np.testing.assert_allclose(t_n, t_j, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(y_n, y_j, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fk_n, fk_j, rtol=0, atol=1e-7)
    assert [i for *_, i in info_n] == [i for *_, i in info_j]


def test_numpy_model_gradients_match_finite_differences():
    """Reverse and forward mode through a hosted model (a damped pendulum with a relay
    torque, in NumPy) in the native solve, against central differences of the solve."""

    def pendulum(t, y):
        return np.array([y[1], -np.sin(y[0]) - 0.3 * y[1] - 0.5 * np.tanh(5 * y[1])])

    y0 = np.array([0.8, -0.2])
    rhs = _host.adapt(pendulum, "fun", "(t, y)", (0.0, y0), (2,))
    assert isinstance(rhs, _host.HostFunction)
    kwargs = dict(
        stepper=nj.Bathe(solver=nj.SemismoothNewton(rtol=1e-12, atol=1e-12)),
        controller=nj.ConstantStepSize(),
        h0=0.05,
        max_steps=24,
    )

    def final(y0, adjoint="checkpointed"):
        sol = nj.solve(lambda t, y, a: rhs(t, y), 0.0, 1.0, y0, adjoint=adjoint, **kwargs)
        return sol.y_final

    final = jax.jit(final, static_argnums=1)
    weights = jnp.array([1.0, -2.0])
    loss = lambda y0, adjoint="checkpointed": weights @ final(y0, adjoint)  # noqa: E731
    eps = 1e-6
    fd = np.array([(loss(y0 + eps * e) - loss(y0 - eps * e)) / (2 * eps) for e in np.eye(2)])
    np.testing.assert_allclose(jax.grad(loss)(y0), fd, rtol=1e-6)
    tangent = np.array([0.3, -0.7])
    _, jvp = jax.jvp(lambda y: loss(y, "forward"), (y0,), (jnp.asarray(tangent),))
    assert float(jvp) == pytest.approx(fd @ tangent, rel=1e-6)


def test_hosted_function_batches_and_differentiates():
    """The hosted function itself: values, Jacobians (forward and reverse, in y and t) and
    a Hessian (finite differences of finite differences) against the analytic ones, under
    one and two levels of `vmap` (with an unbatched argument)."""

    def f(t, y):
        return np.array([y[1] * np.sin(t), -9.81 * y[0] ** 2])

    def exact(t, y):
        value = jnp.array([y[1] * jnp.sin(t), -9.81 * y[0] ** 2])
        d_y = jnp.array([[0.0, jnp.sin(t)], [-19.62 * y[0], 0.0]])
        d_t = jnp.array([y[1] * jnp.cos(t), 0.0])
        return value, d_y, d_t

    F = _host.adapt(f, "fun", "(t, y)", (0.0, np.zeros(2)), (2,))
    ts = jnp.array([0.1, 0.7, 2.0])
    ys = jnp.array([[0.3, -1.2], [1.5, 0.4], [-2.0, 3.0]])
    value, d_y, d_t = jax.vmap(exact)(ts, ys)
    np.testing.assert_allclose(jax.vmap(F)(ts, ys), value, rtol=1e-15)
    np.testing.assert_allclose(
        jax.vmap(F, (None, 0))(0.7, ys), jax.vmap(exact, (None, 0))(0.7, ys)[0]
    )
    np.testing.assert_allclose(jax.vmap(jax.jacfwd(F, 1))(ts, ys), d_y, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(jax.vmap(jax.jacrev(F, 1))(ts, ys), d_y, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(jax.vmap(jax.jacfwd(F, 0))(ts, ys), d_t, rtol=1e-9, atol=1e-9)
    nested = jax.vmap(jax.vmap(F))(jnp.stack([ts, ts + 1]), jnp.stack([ys, 2 * ys]))
    np.testing.assert_allclose(nested[1], jax.vmap(exact)(ts + 1, 2 * ys)[0], rtol=1e-15)
    hessian = jax.hessian(lambda y: F(0.7, y)[1])(ys[0])
    np.testing.assert_allclose(hessian, [[-19.62, 0.0], [0.0, 0.0]], atol=1e-4)


def test_models_that_cannot_work_say_what_to_change():
    """Before any work: a model that writes into its input, one that returns the wrong
    shape, one that neither traces nor runs on NumPy arrays."""
    y0 = np.array([1.0, 0.0])

    def mutates(t, y):
        y[0] = y[1]
        return np.array([y[1], -1.0])

    with pytest.raises(ModelError, match=r"`fun` .* modifies its argument `y` in place"):
        solve_ivp_ns(mutates, (0.0, 1.0), y0)
    with pytest.raises(ModelError, match=r"`fun` .* returned shape \(3,\); expected \(2,\)"):
        solve_ivp_ns(lambda t, y: np.array([y[1], -1.0, 0.0]), (0.0, 1.0), y0)
    with pytest.raises(ModelError, match=r"`fun` .* can neither be traced .* math domain"):
        solve_ivp_ns(lambda t, y: np.array([math.sqrt(y[0] - 5.0), 0.0]), (0.0, 1.0), y0)

    def G_apply(t, y, lam):
        lam[0] = 1.0
        return np.array([0.0, lam[0]])

    opts = dict(gap=lambda t, y: y[:1], J_u=lambda t, y: np.array([[0.0, 1.0]]))
    with pytest.raises(ModelError, match=r"`G_apply` .* modifies its argument `lam`"):
        solve_ivp_ns(
            lambda t, y: jnp.array([y[1], -G]),
            (0.0, 1.0),
            y0,
            projection="unilateral",
            projection_opts=opts | dict(G_apply=G_apply),
        )


def test_float64_whatever_the_x64_mode():
    """The reference computes in float64; so does the drop-in, with x64 off (JAX's
    default) as with it on: the same program, the same numbers, and the caller's mode is
    left as it was."""
    on = ball(jnp)
    with jax.enable_x64(False):
        off = ball(jnp)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NumpyModelWarning)
            off_numpy = ball(np)  # float64 through the host callbacks too
        assert jnp.zeros(1).dtype == jnp.float32
    assert jnp.zeros(1).dtype == jnp.float64
    for a, b in zip(on[:4], off[:4]):
        assert b.dtype == np.float64
        np.testing.assert_array_equal(a, b)
    assert off_numpy[1].dtype == np.float64
    np.testing.assert_allclose(off_numpy[1], on[1], rtol=0, atol=1e-9)
    # float32 would put the ball 1e-7 into the floor (7e-7 once); float64 keeps it out.
    assert np.min(off[1][:, 1]) > -1e-12


def test_t_eval_gives_a_plot_ready_ball():
    """Steps land just before each impact, so the steps alone draw a flat line; `t_eval`
    gives the flights: against the exact ball and against the native scene's `t_eval`."""
    t_eval = np.linspace(0.0, 3.0, 61)
    t, y, h, fk, info = ball(jnp, t_eval=t_eval)
    steps = ball(jnp)
    assert len(steps[0]) < 20  # the per-step output: a handful of points
    np.testing.assert_array_equal(t, t_eval)
    assert y.shape == (61, 2) and len(h) == len(steps[0])
    exact = np.array([ball_exact(s) for s in t_eval])
    np.testing.assert_allclose(y, exact, rtol=0, atol=1e-6)
    scene, _, args = nj.scenes.bouncing_ball(restitution=0.8, height=2.0, velocity=1.0)
    native = scene.solve(
        0.0,
        3.0,
        jnp.array([2.0, 1.0]),
        args,
        stepper=nj.Bathe(solver=nj.SemismoothNewton(rtol=1e-12, atol=1e-12)),
        controller=nj.PIDController(rtol=1e-6, atol=1e-8),
        h0=1e-3,
        t_eval=t_eval,
    )
    np.testing.assert_allclose(y[:, ::-1], native.y_eval, rtol=0, atol=1e-6)
