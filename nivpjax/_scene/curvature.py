"""Whether a contact's gap is affine in the positions, read off its traced Hessian; whether
it reads the time."""

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.core import Literal


def gap_is_affine(gap, positions, t, x, args) -> bool:
    r"""`True` when the Hessian of `gap(t, x, args)` with respect to `x[positions]` is zero
    whatever the state and the parameters: its traced program (`jax.make_jaxpr`, on
    abstract values of `t` and `x`) reads neither of them nor any traced parameter, and
    its value, computed at trace time, is exactly zero. Anything else (a Hessian that
    depends on the state, a constant nonzero one, one that reads traced parameters) counts
    as curved: the conservative side, where closed contacts are held on their gap."""
    pos = np.asarray(positions)
    x = jnp.asarray(x)

    def hessian(t, x):
        def g(q):
            return jnp.atleast_1d(gap(t, x.at[pos].set(q), args))

        return jax.hessian(g)(x[pos])

    t = jnp.asarray(t, x.dtype)
    spec = (jax.ShapeDtypeStruct(t.shape, t.dtype), jax.ShapeDtypeStruct(x.shape, x.dtype))
    closed = jax.make_jaxpr(hessian)(*spec)
    if _reads_inputs(closed.jaxpr):
        return False
    with jax.ensure_compile_time_eval():
        dummy = [jnp.zeros(v.aval.shape, v.aval.dtype) for v in closed.jaxpr.invars]
        out = jax.core.eval_jaxpr(closed.jaxpr, closed.consts, *dummy)
    return all(np.all(np.asarray(o) == 0) for o in out)


def gap_reads_time(gap, t, x, args) -> bool:
    r"""`True` when the traced program of `gap(t, x, args)` carries the time to its value
    (forward data flow from `t` alone; the state and the parameters are held fixed): a
    moving surface, $\partial g/\partial t \ne 0$. Conservative: a program that reads `t`
    and then drops it through a nested call counts as reading it."""
    x = jnp.asarray(x)
    t = jnp.asarray(t, x.dtype)
    closed = jax.make_jaxpr(lambda t: jnp.atleast_1d(gap(t, x, args)))(
        jax.ShapeDtypeStruct(t.shape, t.dtype)
    )
    return _reads_inputs(closed.jaxpr, consts=False)


def _reads_inputs(jaxpr, consts=True) -> bool:
    # Forward data flow from the inputs and the closed-over constants (traced parameters
    # among them; `consts=False`: from the inputs only) to the outputs, over the top-level
    # equations (a nested program's inputs are its equation's inputs, so this is
    # conservative).
    reached = {id(v) for v in (*jaxpr.invars, *(jaxpr.constvars if consts else ()))}
    for eqn in jaxpr.eqns:
        if any(id(v) in reached for v in eqn.invars if not isinstance(v, Literal)):
            reached.update(id(v) for v in eqn.outvars)
    return any(id(v) in reached for v in jaxpr.outvars if not isinstance(v, Literal))
