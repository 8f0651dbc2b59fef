"""nivpjax.learn: the ES estimator on a toy objective, a short training run."""

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
import optax
import pytest

from nivpjax import learn
from nivpjax.learn import tasks


def test_es_gradient_quadratic():
    a = {"w": jnp.array([1.0, 2.0, 0.5]), "b": jnp.array(3.0)}
    c = {"w": jnp.array([0.3, -1.0, 2.0]), "b": jnp.array(-0.5)}
    theta = {"w": jnp.array([1.0, 0.0, -1.0]), "b": jnp.array(0.25)}

    def loss(p):
        return sum(
            jnp.sum(ai * (pi - ci) ** 2) for ai, pi, ci in zip(*map(jax.tree.leaves, (a, p, c)))
        )

    exact = jax.grad(loss)(theta)
    est, losses = jax.jit(lambda t, k: learn.es_gradient(loss, t, k, pairs=20000, sigma=0.1))(
        theta, jr.PRNGKey(0)
    )
    assert losses.shape == (40000,)
    # Antithetic ES is unbiased on a quadratic, with sample-covariance noise of relative size
    # ~ sqrt(d / P) ~ 1.6%: allow 5% of the largest component.
    scale = max(float(jnp.max(jnp.abs(g))) for g in jax.tree.leaves(exact))
    for e, x in zip(jax.tree.leaves(est), jax.tree.leaves(exact)):
        np.testing.assert_allclose(e, x, atol=0.05 * scale)
    # And it is not trivially close: a wrong sign or scale would fail.
    assert float(jnp.abs(exact["b"])) > 0.1 * scale
    # With the centre: the same estimate (the same draws), and L(theta) appended.
    est_c, losses_c = learn.es_gradient(
        loss, theta, jr.PRNGKey(0), pairs=20, sigma=0.1, centre=True
    )
    est_20, _ = learn.es_gradient(loss, theta, jr.PRNGKey(0), pairs=20, sigma=0.1)
    assert losses_c.shape == (41,)
    np.testing.assert_allclose(losses_c[-1], loss(theta), rtol=1e-12)
    for a, b in zip(jax.tree.leaves(est_c), jax.tree.leaves(est_20)):
        np.testing.assert_allclose(a, b, rtol=1e-12)


def test_short_training_improves_objective():
    task = tasks.relay_sliding(t1=1.0, max_steps=300)
    policy = learn.make_policy(task.full_stepper.error_order, key=jr.PRNGKey(0), width=4, depth=1)
    objective = learn.Objective(attempts=1.0, iterations=0.1, rejections=1.0, error=1.0)
    result = learn.train(
        task,
        policy,
        objective=objective,
        optimiser=optax.adam(0.1),
        iterations=3,
        batch=2,
        pairs=2,
        sigma=0.1,
        seed=0,
        progress=False,
    )
    assert len(result.history) == 3
    assert not np.any(result.final.failed)
    assert float(jnp.mean(result.final.cost)) < float(jnp.mean(result.initial.cost))


def test_bad_input():
    task = tasks.relay_sliding()
    with pytest.raises(ValueError, match="method"):
        learn.train(task, None, method="ppo")
    with pytest.raises(ValueError, match="t1"):
        learn.Task(task.scene, task.sample, t1=0.0)


def test_reinforce_runs_in_graph():
    task = tasks.relay_sliding(t1=0.5, max_steps=100)
    env = learn.StepSizeEnv(task)
    policy = learn.make_policy(
        task.full_stepper.error_order,
        key=jr.PRNGKey(0),
        width=4,
        depth=1,
        output_scale=env.action_scale,
    )
    result = learn.train(
        task,
        policy,
        method="reinforce",
        env=env,
        optimiser=optax.adam(1e-2),
        iterations=2,
        batch=3,
        noise=0.1,
        horizon=40,
        progress=False,
    )
    assert len(result.history) == 2
    assert all(np.isfinite(h["objective"]) for h in result.history)
    leaves = jax.tree.leaves(eqx.filter(result.policy, eqx.is_inexact_array))
    assert all(np.all(np.isfinite(x)) for x in leaves)
    # The update moved the policy away from its (PID) start.
    assert float(jnp.max(jnp.abs(result.policy.mlp.layers[-1].weight))) > 0


@pytest.mark.parametrize("name", sorted(tasks.TASKS))
def test_shipped_policies_load(name):
    from nivpjax.learn import pretrained

    task, policy = pretrained.load(name)
    leaves = jax.tree.leaves(eqx.filter(policy, eqx.is_inexact_array))
    assert leaves and all(np.all(np.isfinite(x)) for x in leaves)
    phi = jnp.zeros(nv_features_size())
    assert policy(phi).shape == (1,)


def nv_features_size():
    import nivpjax as nv

    return nv.StepFeatures().size
