"""A trainable step-size policy that starts as the classical controller."""

import equinox as eqx
import jax.numpy as jnp
import jax.random as jr

from .._controller import IntegralPolicy, StepFeatures


class ResidualPolicy(eqx.Module):
    r"""The integral controller plus a learned correction:
    $\text{out} = (\log(\text{safety}) - \phi_0/k + \text{MLP}(s\,\phi)) / c$, with
    $s$ = `input_scale` and $c$ = `output_scale` (use the environment's `action_scale` when
    acting in `nivpjax.rl`, and the same `action_scale` in [`nivpjax.PolicyController`][]).
    The MLP's last layer starts at zero, so an untrained policy is exactly PID."""

    base: IntegralPolicy
    mlp: eqx.nn.MLP
    input_scale: float = 0.1
    output_scale: float = 1.0

    def __call__(self, features):
        correction = self.mlp(self.input_scale * features)
        return (self.base(features) + correction) / self.output_scale


def make_policy(
    order: int,
    *,
    key,
    n_features: int | None = None,
    width: int = 16,
    depth: int = 2,
    output_scale: float = 1.0,
    dtype=None,
) -> ResidualPolicy:
    """A [`nivpjax.learn.ResidualPolicy`][] for `StepFeatures()` (or `n_features`) with an
    MLP of `depth` hidden layers of `width` (tanh), last layer zero."""
    n = StepFeatures().size if n_features is None else n_features
    dtype = jnp.zeros(()).dtype if dtype is None else dtype
    mlp = eqx.nn.MLP(n, 1, width, depth, activation=jnp.tanh, key=key, dtype=dtype)
    last = mlp.layers[-1]
    mlp = eqx.tree_at(
        lambda m: (m.layers[-1].weight, m.layers[-1].bias),
        mlp,
        (jnp.zeros_like(last.weight), jnp.zeros_like(last.bias)),
    )
    return ResidualPolicy(IntegralPolicy(order), mlp, output_scale=output_scale)


def save_policy(path, policy) -> None:
    """Writes the policy's arrays with `equinox.tree_serialise_leaves`."""
    eqx.tree_serialise_leaves(path, policy)


def load_policy(path, like):
    """Reads arrays written by [`nivpjax.learn.save_policy`][] into the structure `like`
    (e.g. `make_policy(order, key=jax.random.PRNGKey(0))`)."""
    return eqx.tree_deserialise_leaves(path, like)


def initial_key(seed: int):
    return jr.PRNGKey(seed)


def trainable(policy):
    """`(params, static)`: the float arrays of the policy and the rest."""
    return eqx.partition(policy, eqx.is_inexact_array)
