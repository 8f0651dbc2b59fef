"""Matrix-free Krylov semismooth Newton against the dense path on mid-size stages: values,
reverse- and forward-mode derivatives, failure reporting, the block-Jacobi preconditioner
and the automatic choice."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj


N = 40  # blocks: 80 unknowns, above the unrolled LU, below AutoLinear's dense_max
DENSE = nj.SemismoothNewton(rtol=1e-12, atol=1e-12, linear_solver=nj.DenseLU())
KRYLOV = nj.SemismoothNewton(rtol=1e-12, atol=1e-12, linear_solver=nj.Krylov())
BICG = nj.SemismoothNewton(
    rtol=1e-12,
    atol=1e-12,
    linear_solver=nj.Krylov(method="bicgstab", max_steps=200, warm_start=True),
)
# Cells (u_i, v_i); block i couples blocks i - 1 and i + 1 only, so colours i mod 3 read
# the diagonal blocks exactly from 6 products.
CELLS = np.stack([np.arange(N), np.arange(N, 2 * N)], axis=1)
PRECONDITIONED = nj.SemismoothNewton(
    rtol=1e-12,
    atol=1e-12,
    linear_solver=nj.Krylov(preconditioner=nj.BlockJacobi(CELLS, np.arange(N) % 3)),
)
SOLVERS = {"krylov": KRYLOV, "bicgstab": BICG, "block-jacobi": PRECONDITIONED}


def _project(projector, y_prev, h):
    def project(z, y, rho):
        ctx = nj.ProjectionContext(t=h, h=h, y_prev=y_prev, y_iter=y, rho=rho, args=None)
        return projector(z, ctx)

    return project


def chain_stage(solver, p, friction=True):
    residual, project, h, y_prev = chain_parts(p, friction)
    return solver.solve(residual, project, h, y_prev)


def chain_parts(p, friction=True):
    r"""`(residual, project, rho, y_prev)` of one backward Euler stage of a driven
    spring-block chain (positions u, velocities v) with slip-weakening Coulomb friction
    $c(u) = p_3 (0.5 + 0.1 e^{-|u|/0.05})$ on every velocity (or, `friction=False`, a
    box $|v_i| \le 0.3$, or nothing when `friction=None`).
    `p = (coupling, drive, step, friction scale)`; the initial state is fixed and
    uneven, so some blocks stick and some slip."""
    kc, drive, h, scale = p[0], p[1], p[2], p[3]
    i = jnp.arange(N, dtype=p.dtype)
    u0 = 0.3 * jnp.sin(1.7 * i)
    v0 = 0.5 * jnp.cos(0.9 * i)
    y_prev = jnp.concatenate([u0, v0])

    def residual(y):
        u, v = y[:N], y[N:]
        lap = jnp.concatenate([u[1:2] - u[:1], u[2:] - 2 * u[1:-1] + u[:-2], u[-2:-1] - u[-1:]])
        force = kc * lap + (drive - u)
        return jnp.concatenate([(u - u0) / h - v, (v - v0) / h - force])

    velocities = tuple(range(N, 2 * N))
    if friction is None:
        projector = nj.Identity()
    elif friction:
        bound = lambda t, y, a: scale * (0.5 + 0.1 * jnp.exp(-jnp.abs(y[:N]) / 0.05))
        projector = nj.BlockProjector([(velocities, nj.CoulombFriction(bound))])
    else:
        projector = nj.BlockProjector([(velocities, nj.Box(-0.3 * scale, 0.3 * scale))])
    return residual, _project(projector, y_prev, h), h, y_prev


P0 = jnp.array([4.0, 0.2, 0.3, 2.0])


@eqx.filter_jit
def value(solver, p, friction=True):
    return chain_stage(solver, p, friction)


@eqx.filter_jit
def value_and_grad(solver, p, friction=True):
    def loss(q):
        sol = chain_stage(solver, q, friction)
        return jnp.sum(jnp.sin(jnp.arange(2 * N)) * sol.value), sol

    (_, sol), grad = jax.value_and_grad(loss, has_aux=True)(p)
    return sol, grad


@eqx.filter_jit
def tangent(solver, p, dp, friction=True):
    return jax.jvp(lambda q: chain_stage(solver, q, friction).value, (p,), (dp,))[1]


@pytest.fixture(scope="module")
def dense():
    return {f: value_and_grad(DENSE, P0, f) for f in (True, False)}


CASES = [(name, True) for name in SOLVERS] + [("krylov", False)]


@pytest.mark.parametrize("name, friction", CASES)
def test_matrix_free_matches_dense_values_and_gradients(dense, name, friction):
    ref, ref_grad = dense[friction]
    assert ref.result == nj.RESULTS.successful
    # The stage has blocks on both sides of every kink: sticking and slipping, or on the
    # box's faces and inside.
    v = np.abs(np.asarray(ref.value[N:]))
    if friction:
        assert 5 < np.sum(v < 1e-12) < N - 5
    else:
        assert 5 < np.sum(np.abs(v - 0.3 * P0[3]) < 1e-12) < N - 5
    sol, grad = value_and_grad(SOLVERS[name], P0, friction)
    assert sol.result == nj.RESULTS.successful
    assert sol.linear_iterations > 0
    np.testing.assert_allclose(sol.value, ref.value, rtol=0, atol=1e-10)
    np.testing.assert_allclose(grad, ref_grad, rtol=1e-7, atol=1e-9)


def test_vi_method_derivatives_through_krylov_match_dense(dense):
    # FixedPointVI needs no linear solve to iterate; its implicit-function derivatives go
    # through its linear_solver (matrix-free here).
    vi = nj.FixedPointVI(rtol=1e-12, atol=1e-12, max_steps=5000, linear_solver=nj.Krylov())
    ref, ref_grad = dense[True]
    sol, grad = value_and_grad(vi, P0)
    assert sol.result == nj.RESULTS.successful
    np.testing.assert_allclose(sol.value, ref.value, rtol=0, atol=1e-10)
    np.testing.assert_allclose(grad, ref_grad, rtol=1e-7, atol=1e-9)


def test_smooth_stage_matches_dense():
    # No projector: a plain implicit step.
    ref, sol = value(DENSE, P0, None), value(KRYLOV, P0, None)
    assert sol.result == nj.RESULTS.successful
    np.testing.assert_allclose(sol.value, ref.value, rtol=0, atol=1e-10)


def test_forcing_terms_tighten_into_superlinear_convergence():
    # Eisenstat-Walker: loose linear solves first, then accurate ones, so the residual
    # ratios of the last iterations fall far below any fixed forcing term (a fixed
    # eta = 0.5 would leave them near 0.5).
    sol = value(KRYLOV, P0)
    k = int(sol.iterations)
    history = np.asarray(sol.history[: k + 1])
    ratios = history[1:] / history[:-1]
    assert k >= 3
    assert ratios[0] > 0.05  # the first solve is loose
    assert ratios[-2] < 1e-2 and ratios[-1] < 1e-2


def test_dense_gradient_matches_finite_differences(dense):
    # Anchors the comparison above to an independent reference (central differences;
    # the active set does not change within 1e-6).
    _, grad = dense[True]
    eps = 1e-6
    loss = lambda q: float(jnp.sum(jnp.sin(jnp.arange(2 * N)) * value(DENSE, q).value))
    fd = [(loss(P0.at[k].add(eps)) - loss(P0.at[k].add(-eps))) / (2 * eps) for k in range(4)]
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-8)


def test_forward_mode_matches_dense():
    dp = jnp.array([0.3, -1.0, 0.05, 0.7])
    ref = tangent(DENSE, P0, dp)
    np.testing.assert_allclose(tangent(KRYLOV, P0, dp), ref, rtol=0, atol=1e-9)


def test_an_exact_preconditioner_solves_in_one_krylov_cycle():
    # One block holding every unknown: M is the inverse Jacobian, so right-preconditioned
    # GMRES solves G' M z = -G with its first product at every Newton iteration (a wrong
    # transpose or ordering of the blocks would not; nor would a GMRES that fills its
    # cycle before testing).
    # BiCGStab (lineax's) likewise takes one iteration, once lineax's test on the last
    # update is kept out of the way (`Krylov._solve`).
    inverse = nj.BlockJacobi(np.arange(2 * N)[None, :])
    for exact in (
        nj.Krylov(preconditioner=inverse, restart=4),
        nj.Krylov(preconditioner=inverse, method="bicgstab"),
    ):
        sol = value(nj.SemismoothNewton(rtol=1e-12, atol=1e-12, linear_solver=exact), P0)
        assert sol.result == nj.RESULTS.successful
        assert sol.linear_iterations == sol.iterations


def test_block_jacobi_reads_the_diagonal_blocks_exactly():
    rng = np.random.default_rng(0)
    n = 2 * N
    # A matrix with the chain's pattern: cell i coupled to cells i - 1 and i + 1.
    J = np.zeros((n, n))
    for i in range(N):
        for j in (i - 1, i, i + 1):
            if 0 <= j < N:
                J[np.ix_(CELLS[i], CELLS[j])] = rng.standard_normal((2, 2))
    J[np.ix_(CELLS[0], CELLS[0])] += 5 * np.eye(2)
    A = jnp.asarray(J)
    x = jnp.asarray(rng.standard_normal(n))
    expected = np.zeros(n)
    for i in range(N):
        expected[CELLS[i]] = np.linalg.solve(J[np.ix_(CELLS[i], CELLS[i])], x[CELLS[i]])
    for pre in (nj.BlockJacobi(CELLS, np.arange(N) % 3), nj.BlockJacobi(CELLS)):
        apply, apply_t = pre.build(lambda v: A @ v, n, A.dtype)
        np.testing.assert_allclose(apply(x), expected, rtol=1e-10)
        expected_t = np.zeros(n)
        for i in range(N):
            block = J[np.ix_(CELLS[i], CELLS[i])].T
            expected_t[CELLS[i]] = np.linalg.solve(block, x[CELLS[i]])
        np.testing.assert_allclose(apply_t(x), expected_t, rtol=1e-10)
    # The default is the diagonal.
    apply, _ = nj.BlockJacobi().build(lambda v: A @ v, n, A.dtype)
    np.testing.assert_allclose(apply(x), x / np.diag(J), rtol=1e-12)


def test_starved_krylov_never_reports_a_wrong_success():
    # One Arnoldi vector per solve and few Newton iterations: the stage is either solved
    # to its tolerance anyway (inexact Newton with a line search) or reported unsolved.
    starved = nj.SemismoothNewton(
        rtol=1e-12,
        atol=1e-12,
        max_steps=4,
        linear_solver=nj.Krylov(restart=1, max_steps=1),
    )
    sol = value(starved, P0)
    assert sol.result != nj.RESULTS.successful
    ref = value(DENSE, P0)
    assert float(jnp.max(jnp.abs(sol.value - ref.value))) > 1e-6


def test_unconverged_tangent_solve_gives_nan_not_a_wrong_derivative():
    starved = nj.SemismoothNewton(
        rtol=1e-12,
        atol=1e-12,
        # One GMRES cycle of 5 products (lineax's first step is a dummy): short of 1e-10.
        linear_solver=nj.Krylov(tangent_max_steps=2),
    )
    sol, grad = value_and_grad(starved, P0)
    assert sol.result == nj.RESULTS.successful
    assert np.all(np.isnan(grad))
    assert np.all(np.isnan(tangent(starved, P0, jnp.ones(4))))


def test_auto_is_dense_up_to_its_threshold_and_krylov_above():
    assert isinstance(nj.AutoLinear().resolve(128), nj.DenseLU)
    assert isinstance(nj.AutoLinear().resolve(129), nj.Krylov)
    assert isinstance(nj.AutoLinear(dense_max=10).resolve(2 * N), nj.Krylov)
    auto = nj.SemismoothNewton(rtol=1e-12, atol=1e-12)
    assert value(auto, P0).linear_iterations == 0  # 80 unknowns: dense
    small = nj.SemismoothNewton(rtol=1e-12, atol=1e-12, linear_solver=nj.AutoLinear(dense_max=10))
    assert value(small, P0).linear_iterations > 0


def test_bad_linear_solver_options_raise():
    with pytest.raises(ValueError, match="method"):
        nj.Krylov(method="cg")
    with pytest.raises(ValueError, match="restart"):
        nj.Krylov(restart=0)
    with pytest.raises(ValueError, match="eta_max"):
        nj.Krylov(eta_max=1.5)
    with pytest.raises(TypeError, match="preconditioner"):
        nj.Krylov(preconditioner="jacobi")
    with pytest.raises(TypeError, match="linear_solver"):
        nj.SemismoothNewton(linear_solver="krylov")
    with pytest.raises(ValueError, match="blocks"):
        nj.BlockJacobi(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="blocks"):
        nj.BlockJacobi(np.zeros((3, 1), int)).build(lambda v: v, 3, jnp.float64)


def _trajectory_loss(linear_solver, n=20):
    # A friction chain over 12 fixed Bathe steps through nj.solve: the implicit-function
    # solves of every stage are transposed inside the checkpointed loop.
    def dynamics(t, x, a, m):
        u, v = x[:n], x[n:]
        lap = jnp.concatenate([u[1:2] - u[:1], u[2:] - 2 * u[1:-1] + u[:-2], u[-2:-1] - u[-1:]])
        return jnp.concatenate([v, a["kc"] * lap + (0.5 * t - u)])

    bound = lambda t, x, a: a["c"] * (0.5 + 0.1 * jnp.exp(-jnp.abs(x[:n]) / 0.05))
    scene = nj.Scene(dynamics, 2 * n, (nj.Friction(np.arange(n, 2 * n), bound),))
    x0 = jnp.concatenate([0.3 * jnp.sin(1.7 * jnp.arange(n)), jnp.zeros(n)])
    stepper = nj.Bathe(
        solver=nj.SemismoothNewton(rtol=1e-12, atol=1e-12, linear_solver=linear_solver)
    )

    def loss(p):
        sol = scene.solve(
            0.0,
            1.2,
            x0,
            {"kc": p[0], "c": p[1]},
            stepper=stepper,
            controller=nj.ConstantStepSize(),
            h0=0.1,
            max_steps=16,
            saveat=nj.SaveAt(),
        )
        return jnp.sum(jnp.cos(jnp.arange(2 * n)) * sol.y_final)

    return loss


def test_gradient_through_a_whole_solve_matches_dense():
    p = jnp.array([4.0, 1.5])
    v_dense, g_dense = jax.value_and_grad(_trajectory_loss(nj.DenseLU()))(p)
    v_krylov, g_krylov = jax.value_and_grad(_trajectory_loss(nj.Krylov()))(p)
    assert np.all(np.isfinite(g_dense)) and np.all(g_dense != 0)
    np.testing.assert_allclose(v_krylov, v_dense, rtol=1e-9)
    np.testing.assert_allclose(g_krylov, g_dense, rtol=1e-6)


def test_linearised_natural_map_from_the_known_argument_is_the_jvp():
    # Semismooth Newton's Krylov operator: R and P linearised apart at the known
    # z = y - rho R(y) must equal the JVP of the natural map G, including the bound's
    # dependence on the state (the slip-weakening friction reads u through the context).
    from nivpjax._nonlinear.base import linearised_natural_map, natural_map

    residual, project, rho, y_prev = chain_parts(P0)
    rng = np.random.default_rng(4)
    y = y_prev + 0.05 * jnp.asarray(rng.standard_normal(2 * N))
    z = y - rho * residual(y)
    lin = linearised_natural_map(residual, project, rho, y, z)
    G = natural_map(residual, project, rho)
    for _ in range(3):
        v = jnp.asarray(rng.standard_normal(2 * N))
        expected = jax.jvp(G, (y,), (v,))[1]
        np.testing.assert_allclose(lin(v), expected, rtol=0, atol=1e-12)
    # The bound's state dependence matters here: without the y-part of P's derivative
    # the products differ.
    _, dP = jax.linearize(lambda z_, y_: project(z_, y_, rho), z, y)
    v = jnp.asarray(rng.standard_normal(2 * N))
    assert float(jnp.max(jnp.abs(dP(v, v) - dP(v, jnp.zeros_like(v))))) > 1e-3
