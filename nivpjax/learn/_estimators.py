"""Gradient estimators for step-size policies: antithetic evolution strategies over
forward rollouts, and REINFORCE with a baseline over in-graph episodes."""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
from jax.flatten_util import ravel_pytree

from ._env import EnvParams, StepSizeEnv


def es_gradient(
    loss: Callable, params, key, *, pairs: int = 8, sigma: float = 0.05, centre: bool = False
):
    r"""Antithetic evolution-strategies estimate of $\nabla_\theta \mathbb{E}[L]$ of a
    Gaussian smoothing of `loss`:

    $$ g = \frac{1}{2\sigma P}\sum_{i=1}^{P} \big(L(\theta + \sigma\varepsilon_i)
       - L(\theta - \sigma\varepsilon_i)\big)\,\varepsilon_i,\qquad
       \varepsilon_i \sim \mathcal N(0, I). $$

    Only forward evaluations, all in one `vmap` over the $2P$ perturbations; unaffected by
    the discreteness of accept/reject. Exact in expectation for quadratics.

    **Arguments:** `loss` (`params -> scalar`, vmappable), `params` (a pytree of float
    arrays), `key`, `pairs` $P$, `sigma` $\sigma$, `centre`: also evaluate $L(\theta)$,
    batched with the perturbations (one program holds one copy of `loss`, not two; a
    training step wants the value it descends from).

    **Returns:** `(g, losses)`: the estimate (shaped like `params`) and the $2P$ losses,
    with $L(\theta)$ appended as a last, $(2P + 1)$-th, where `centre`.
    """
    flat, unravel = ravel_pytree(params)
    eps = jr.normal(key, (pairs, flat.shape[0]), flat.dtype)
    thetas = [flat + sigma * eps, flat - sigma * eps] + ([flat[None]] if centre else [])
    thetas = jnp.concatenate(thetas)
    losses = jax.vmap(lambda th: loss(unravel(th)))(thetas)
    diff = losses[:pairs] - losses[pairs : 2 * pairs]
    g = jnp.einsum("p,pd->d", diff, eps) / (2 * sigma * pairs)
    return unravel(g), losses


def gaussian_log_prob(x, mean, std):
    return -0.5 * ((x - mean) / std) ** 2 - jnp.log(std) - 0.5 * jnp.log(2 * jnp.pi)


def collect_episodes(
    env: StepSizeEnv, policy, reset_keys, noise_keys, *, horizon: int, noise: float, params=None
):
    """Runs one episode per key pair in the graph (`vmap` over the keys: `reset_keys` draw
    the scene, `noise_keys` the actions; `lax.scan` over `horizon`
    steps) with the stochastic policy $a \\sim \\mathcal N(\\text{policy}(o)_0,
    \\text{noise}^2)$. Returns `(obs, actions, alive, returns)` with shapes
    `(B, T, f)`, `(B, T)`, `(B, T)`, `(B,)`; `alive` masks the steps before the end."""
    params = EnvParams() if params is None else params

    def episode(reset_key, noise_key):
        obs, state = env.reset(reset_key, params)

        def body(carry, k):
            obs, state = carry
            mean = jnp.atleast_1d(policy(obs))[0]
            action = mean + noise * jr.normal(k, (), mean.dtype)
            alive = ~state.done
            obs2, state2, reward, _, _ = env.step(k, state, action, params)
            return (obs2, state2), (obs, action, alive, reward)

        ks = jr.split(noise_key, horizon)
        (_, last), (o, a, alive, r) = jax.lax.scan(body, (obs, state), ks)
        # An episode still running at the horizon pays the failure cost.
        unfinished = ~last.done
        total = jnp.sum(r) - jnp.where(unfinished, params.objective.failure, 0.0)
        return o, a, alive, total

    return jax.vmap(episode)(reset_keys, noise_keys)


def reinforce_gradient(policy, obs, actions, alive, returns, *, noise: float):
    r"""REINFORCE with a mean baseline: the gradient of the expected cost $-R$,

    $$ g = -\frac{1}{B}\sum_b (R_b - \bar R)\sum_t \nabla_\theta \log
       \pi_\theta(a_{b,t}\mid o_{b,t}), $$

    with log-probabilities recomputed from the collected observations and actions.
    Returns the gradient with respect to the inexact arrays of `policy`."""
    advantage = jax.lax.stop_gradient(returns - jnp.mean(returns))
    obs, actions, alive = jax.lax.stop_gradient((obs, actions, alive))

    def surrogate(p):
        means = jax.vmap(jax.vmap(lambda o: jnp.atleast_1d(p(o))[0]))(obs)
        logp = jnp.sum(jnp.where(alive, gaussian_log_prob(actions, means, noise), 0.0), axis=1)
        return -jnp.mean(advantage * logp)

    return eqx.filter_grad(surrogate)(policy)
