"""nivpjax's restarted GMRES (the Newton directions of `nj.Krylov()`): residuals against the
tolerance, the product on which it stops, restarts, warm starts and failure."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nivpjax._linear.gmres import gmres


def _matrix(n, seed, shift=4.0):
    rng = np.random.default_rng(seed)
    return jnp.asarray(shift * np.eye(n) + rng.standard_normal((n, n)) / np.sqrt(n))


@jax.jit
def _solve(A, b, tol, x0, r0):
    # restart 6, at most 20 cycles; one compiled program for every case below.
    return gmres(lambda v: A @ v, b, tol, 6, 20, x0, r0)


def _run(A, b, tol, x0=None):
    x0 = jnp.zeros_like(b) if x0 is None else x0
    return _solve(A, b, tol, x0, b - A @ x0)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("rel", [1e-1, 1e-4, 1e-10])
def test_true_residual_meets_the_tolerance(seed, rel):
    A = _matrix(30, seed, shift=1.5)  # needs restarts at tight tolerances
    b = jnp.asarray(np.random.default_rng(10 + seed).standard_normal(30))
    tol = rel * float(jnp.linalg.norm(b))
    x, converged, products = _run(A, b, tol)
    assert bool(converged)
    assert float(jnp.linalg.norm(b - A @ x)) <= 1.01 * tol
    # Minimal residual: the loosest tolerance is met within one short cycle.
    if rel == 1e-1:
        assert int(products) <= 6


def test_stops_at_the_product_that_meets_the_tolerance():
    # A = I + u v^T has two distinct eigenvalues: its Krylov space from any b holds the
    # solution after two products; a solver that filled its cycle would report 6.
    rng = np.random.default_rng(3)
    u, v = rng.standard_normal(40), rng.standard_normal(40)
    A = jnp.asarray(np.eye(40) + 0.3 * np.outer(u, v) / 40)
    b = jnp.asarray(rng.standard_normal(40))
    x, converged, products = _run(A, b, 1e-12 * float(jnp.linalg.norm(b)))
    assert bool(converged) and int(products) == 2
    np.testing.assert_allclose(A @ x, b, rtol=0, atol=1e-11)
    # The identity: one product.
    _, converged, products = _run(jnp.eye(40), b, 1e-12)
    assert bool(converged) and int(products) == 1


def test_restarts_recompute_the_residual_and_count_it():
    A = _matrix(30, 0, shift=1.2)
    b = jnp.asarray(np.random.default_rng(0).standard_normal(30))
    x, converged, products = _run(A, b, 1e-10 * float(jnp.linalg.norm(b)))
    assert bool(converged)
    assert int(products) > 7  # a full cycle of 6, the restart's product, and more
    np.testing.assert_allclose(x, np.linalg.solve(np.asarray(A), np.asarray(b)), rtol=1e-8)


def test_a_warm_start_at_the_solution_costs_nothing():
    A = _matrix(30, 1)
    b = jnp.asarray(np.random.default_rng(1).standard_normal(30))
    exact = jnp.asarray(np.linalg.solve(np.asarray(A), np.asarray(b)))
    x, converged, products = _run(A, b, 1e-8, x0=exact)
    assert bool(converged) and int(products) == 0
    np.testing.assert_array_equal(x, exact)
    # A warm start elsewhere converges to the same solution.
    x, converged, _ = _run(A, b, 1e-12, x0=exact + 1.0)
    assert bool(converged)
    np.testing.assert_allclose(x, exact, rtol=0, atol=1e-10)


def test_exhausted_cycles_report_no_convergence():
    A = _matrix(30, 2, shift=0.3)  # far from the identity: 6 products reach little
    b = jnp.asarray(np.random.default_rng(2).standard_normal(30))
    x, converged, products = gmres(lambda v: A @ v, b, 1e-12, 2, 1)
    assert not bool(converged)
    assert int(products) == 2
    assert float(jnp.linalg.norm(b - A @ x)) > 1e-12


def test_gram_schmidt_twice_keeps_the_residual_true_when_the_basis_is_ill_conditioned():
    # Non-normal, eigenvalues from 1 to 1e10, one cycle of 80 products asked for 1e-12:
    # beyond reach in float64, but orthogonalising twice keeps the true residual within a
    # few 1e-7, where once lets the basis lose orthogonality and the residual stay above
    # 4e-4 (measured on these three seeds).
    n = 80
    for seed in range(3):
        rng = np.random.default_rng(seed)
        T = np.triu(rng.standard_normal((n, n)), 1) * 2 + np.diag(np.logspace(0, 10, n))
        Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
        A = jnp.asarray(Q @ T @ Q.T)
        b = jnp.asarray(rng.standard_normal(n))
        x, _, _ = gmres(lambda v: A @ v, b, 1e-12 * float(jnp.linalg.norm(b)), n, 1)
        assert float(jnp.linalg.norm(b - A @ x) / jnp.linalg.norm(b)) < 1e-5
