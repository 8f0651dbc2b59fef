"""`tangent_only`: a term zero in value is skipped by the primal computation and
differentiated as written, through every transformation a solve goes through."""

import jax
import jax.numpy as jnp
import numpy as np

from nivpjax._tangent import tangent_only


jax.config.update("jax_enable_x64", True)
sg = jax.lax.stop_gradient


def _term(y, k, n):
    # Zero in value, with derivatives in y, in k and through an integer n.
    return jnp.sin(y) * k * n * (y - sg(y)) + (k - sg(k)) * y**2


def _with(y, k, n):
    return y**2 + tangent_only(lambda v: _term(v, k, n), y)


def _written(y, k, n):
    return y**2 + _term(y, k, n)


def test_derivatives_match_the_written_term():
    y, k = jnp.array([0.1, 0.7]), jnp.array([1.3, 2.0])
    n = jnp.array([2, 3])
    for transform in (
        lambda f: jax.vmap(jax.grad(f, argnums=(0, 1)), (0, 0, 0)),
        lambda f: jax.jit(jax.vmap(jax.jacfwd(f, argnums=(0, 1)), (0, 0, 0))),
        lambda f: jax.vmap(jax.hessian(f), (0, 0, 0)),
    ):
        got, want = transform(_with)(y, k, n), transform(_written)(y, k, n)
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
            np.testing.assert_allclose(a, b, rtol=1e-14)
    np.testing.assert_array_equal(_with(y, k, n), y**2)


def test_gradient_through_a_checkpointed_loop():
    def loop(f):
        body = jax.checkpoint(lambda c: c + 0.1 * f(c, 1.3, 3))
        return lambda y: jax.lax.fori_loop(0, 4, lambda i, c: body(c), y)

    np.testing.assert_allclose(jax.grad(loop(_with))(0.7), jax.grad(loop(_written))(0.7))


def test_primal_does_not_evaluate_the_term():
    jaxpr = str(jax.make_jaxpr(_with)(0.7, 1.3, 3))
    assert "sin" not in jaxpr
    assert "sin" in str(jax.make_jaxpr(jax.grad(_with))(0.7, 1.3, 3))
