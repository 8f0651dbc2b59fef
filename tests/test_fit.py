"""`nivpjax.fit`: Levenberg–Marquardt through the solver recovers known parameters from
noisy synthetic data, and its Gauss–Newton covariance matches an independent computation
(central-difference Jacobian)."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import nivpjax as nj


jax.config.update("jax_enable_x64", True)

# x' = -w + b, w in sign(x), from x0 < 0: crosses x = 0 (a relay switch) at
# tau = -x0/(1+b), then x = (b - 1)(t - tau). Parameters (x0, b), observations of x.
TIMES = jnp.linspace(0.05, 1.0, 20)
TRUE = {"x0": jnp.asarray(-0.5), "b": jnp.asarray(1.5)}
NOISE = 0.01


def _model(params):
    def dynamics(t, x, a, m):
        return -m["w"] + a["b"]

    scene = nj.Scene(dynamics, 1, (nj.Relay("w", lambda t, x, a: x[:1]),))
    sol = scene.solve(
        0.0,
        1.0,
        params["x0"][None],
        {"b": params["b"]},
        stepper=nj.BackwardEuler(),
        controller=nj.PIDController(rtol=1e-6, atol=1e-9),
        t_eval=TIMES,
        max_steps=1024,
        adjoint="forward",
        throw=False,
    )
    return sol.y_eval[:, 0]


def _exact(params):
    x0, b = params["x0"], params["b"]
    tau = -x0 / (1 + b)
    return jnp.where(TIMES < tau, x0 + (1 + b) * TIMES, (b - 1) * (TIMES - tau))


DATA = _exact(TRUE) + NOISE * jax.random.normal(jax.random.PRNGKey(0), TIMES.shape)


def _residuals(params, data):
    return _model(params) - data


@pytest.fixture(scope="module")
def fitted():
    start = {"x0": jnp.asarray(-0.3), "b": jnp.asarray(2.0)}  # 40% and 33% off
    return jax.jit(lambda p, d: nj.fit(_residuals, p, d))(start, DATA)


def test_fit_recovers_parameters(fitted):
    assert fitted.result == optx.RESULTS.successful
    for name in ("x0", "b"):
        error = abs(float(fitted.params[name] - TRUE[name]))
        # Within three standard errors, which are a few percent of the value at most.
        assert error < 3 * float(fitted.stderr[name]), (name, error, fitted.stderr[name])
        assert float(fitted.stderr[name]) < 0.03 * abs(float(TRUE[name]))
    history = np.asarray(fitted.history)
    steps = int(fitted.steps)
    assert np.all(np.isfinite(history[: steps + 1])) and np.all(np.isnan(history[steps + 1 :]))
    assert history[steps] < 1e-2 * history[0]
    np.testing.assert_allclose(history[steps], fitted.cost, rtol=1e-10)


def test_fit_covariance_matches_independent_computation(fitted):
    # Central differences of the exact model at the estimate, and sigma from the exact
    # residuals: independent of the solver's derivatives.
    p = fitted.params
    cols = []
    for name in ("b", "x0"):  # ravel_pytree order: sorted keys
        h = 1e-6
        up = dict(p, **{name: p[name] + h})
        down = dict(p, **{name: p[name] - h})
        cols.append((_exact(up) - _exact(down)) / (2 * h))
    J = np.stack(cols, axis=1)
    r = np.asarray(_exact(p) - DATA)
    sigma2 = r @ r / (r.size - 2)
    cov = sigma2 * np.linalg.inv(J.T @ J)
    np.testing.assert_allclose(fitted.covariance, cov, rtol=2e-2)
    np.testing.assert_allclose(fitted.sigma**2, sigma2, rtol=2e-2)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(max_steps=0), ValueError, "`max_steps`"),
        (dict(solver=optx.BFGS(rtol=1e-6, atol=1e-6)), TypeError, "`solver`"),
        (dict(sigma=-1.0), ValueError, "`sigma`"),
    ],
)
def test_fit_bad_input(kwargs, error, match):
    with pytest.raises(error, match=match):
        nj.fit(lambda p, a: p - 1.0, jnp.zeros(2), **kwargs)


def test_fit_bad_params0():
    with pytest.raises(TypeError, match="`params0`"):
        nj.fit(lambda p, a: p, jnp.arange(3))


@pytest.mark.parametrize(
    "solver",
    [
        optx.GaussNewton(rtol=1e-10, atol=1e-10),  # history read off the solver's state
        optx.BestSoFarLeastSquares(optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10)),  # evaluated
    ],
)
def test_fit_history_ends_at_the_cost_of_the_result(solver):
    # Rosenbrock's residuals (minimum 0 at (1, 1)): no solve, so both ways of filling the
    # history are checked against the cost of the returned parameters.
    def residuals(p, args):
        return jnp.stack([10 * (p[1] - p[0] ** 2), 1 - p[0]])

    out = nj.fit(residuals, jnp.array([-1.2, 1.0]), solver=solver, max_steps=200, sigma=1.0)
    steps = int(out.steps)
    history = np.asarray(out.history)
    expected = 0.5 * np.sum(np.asarray(residuals(out.params, None)) ** 2)
    np.testing.assert_allclose(history[steps], expected, rtol=1e-10, atol=1e-30)
    start = 0.5 * np.sum(np.asarray(residuals(jnp.array([-1.2, 1.0]), None)) ** 2)
    np.testing.assert_allclose(history[0], start, rtol=1e-12)
    np.testing.assert_allclose(out.residuals, residuals(out.params, None), rtol=1e-12)
    J = jax.jacfwd(residuals)(out.params, None)
    np.testing.assert_allclose(out.jacobian, J, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(out.params, [1.0, 1.0], atol=1e-6)


def _count(jaxpr, name):
    n = 0
    for eqn in jaxpr.eqns:
        n += eqn.primitive.name == name
        for value in eqn.params.values():
            for sub in value if isinstance(value, (list, tuple)) else [value]:
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    n += _count(inner, name)
    return n


@pytest.mark.parametrize(
    "solver",
    [optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8), optx.Dogleg(rtol=1e-8, atol=1e-8)],
)
def test_fit_program_holds_the_residual_once(solver):
    # A residual with one while loop (as a solve has): the fit's program holds the fit's
    # own loop and one copy of the residual's, inside the Jacobian the solver's steps and
    # the covariance share. Evaluating the start's cost, the solver's linear map and the
    # final Jacobian separately would each add a copy (a solve's compile time each).
    def residuals(p, args):
        def body(carry):
            i, y = carry
            return i + 1, y + 0.01 * p[0] * y

        _, y = jax.lax.while_loop(lambda c: c[0] < args["n"], body, (0, jnp.ones(3)))
        return y + p[1] - args["data"]

    args = {"n": jnp.asarray(10), "data": jnp.arange(3.0)}
    p0 = jnp.array([0.1, 0.2])
    jaxpr = jax.make_jaxpr(lambda p: nj.fit(residuals, p, args, solver=solver))(p0).jaxpr
    assert _count(jaxpr, "while") == 1 + 1
    out = nj.fit(residuals, p0, args, solver=solver, max_steps=100)
    np.testing.assert_allclose(out.jacobian, jax.jacfwd(residuals)(out.params, args), rtol=1e-12)
    cost0 = 0.5 * np.sum(np.asarray(residuals(p0, args)) ** 2)
    np.testing.assert_allclose(out.history[0], cost0, rtol=1e-12)
