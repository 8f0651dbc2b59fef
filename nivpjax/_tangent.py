"""Sensitivity terms that are zero in value: skipped by solves that are not differentiated."""

import functools as ft

import jax
import jax.extend
import jax.numpy as jnp


def tangent_only(fn, *args):
    r"""`fn(*args)` for a function that is zero in value (a sensitivity term such as a
    saltation shift $(f^- - f^+)\,(\tau - \text{stop\_gradient}(\tau))$), without
    evaluating it: zeros of its output's shape and dtype, whose derivative is `fn`'s.

    A solve that is not differentiated then skips the work (the switch shifts of a relay
    stage cost a third of its attempt); `jax.jvp`, `jax.grad` and `jax.vmap` see `fn` as
    written. Every value `fn` closes over (tracers of enclosing transformations included,
    integer ones too, which `jax.closure_convert` would leave closed over) becomes an
    argument, so derivatives through them are kept."""
    flat, tree = jax.tree.flatten(args)
    closed, shapes = jax.make_jaxpr(
        lambda *leaves: fn(*jax.tree.unflatten(tree, leaves)), return_shape=True
    )(*flat)
    out_tree = jax.tree.structure(shapes)

    def converted(*inputs):
        leaves, consts = inputs[: len(flat)], inputs[len(flat) :]
        out = jax.extend.core.jaxpr_as_fun(closed.replace(consts=list(consts)))(*leaves)
        return jax.tree.unflatten(out_tree, out)

    return _zero(converted, tuple(closed.consts), tuple(flat))


@ft.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _zero(fn, consts, args):
    shapes = jax.eval_shape(fn, *args, *consts)
    # Zeros that depend on every input, so that under `vmap` they are batched wherever the
    # derivative is (the primal and tangent outputs of a custom JVP must batch alike, or
    # the batched program mixes their shapes); XLA folds the constant `select` away.
    leaves = jax.tree.leaves((consts, args))
    seed = sum((jnp.where(False, jnp.sum(x), 0).astype(jnp.float32) for x in leaves), 0.0)
    return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype) + seed.astype(s.dtype), shapes)


@_zero.defjvp
def _zero_jvp(fn, primals, tangents):
    consts, args = primals
    d_consts, d_args = tangents
    out, d_out = jax.jvp(lambda c, a: fn(*a, *c), (consts, args), (d_consts, d_args))
    return jax.tree.map(jnp.zeros_like, out), d_out
