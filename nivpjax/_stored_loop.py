r"""Reverse mode through the time loop with every attempted step stored.

A `lax.while_loop` whose reverse mode is a `jax.custom_vjp`. Differentiated, the forward
pass runs the step linearised once (`jax.vjp` of it, traced once and evaluated in the
loop) and stores, per iteration, the residuals of its VJP (`max_steps` rows; residuals that
are the loop's constants are not stored); the backward pass walks back through them,
applying each VJP (transposition only: no step is recomputed), with the output buffers'
cotangents read at the rows each step wrote. When the residuals exceed `STORE_BUDGET_BYTES`
the forward pass stores the loop state instead (the per-step output buffers excepted) and
the backward pass linearises the step again at each. Not differentiated, it is the plain
loop.

It gives the same derivatives as `equinox.internal.while_loop(kind="checkpointed")` (the
same VJP of the same step at the same states, summed in the same order; 1 ulp in tests),
without that loop's analyses of which state is perturbed (each a linearisation of the
step, run to a fixed point under `jax.eval_shape`, two of them nested in the outer trace),
which took about two thirds of the tracing time of a first gradient. Here every float leaf
of the state is treated as perturbed (JAX's symbolic zeros inside the step's VJP drop what
does not depend on the inputs) and the constants as the custom VJP's symbolic zeros say.

The step is converted to a closed jaxpr first (`_convert`): every value it closes over,
tracers of enclosing transformations included (integer ones too, which `jax.closure_convert`
would leave closed over), becomes an argument of the custom VJP.
"""

import jax
import jax.extend
import jax.numpy as jnp
import numpy as np
from jax import lax


# The memory the forward pass may use to store what reverse mode needs of each iteration
# (per batch member under `vmap`).
STORE_BUDGET_BYTES = 64 * 2**20


def stored_bytes(state, max_steps: int) -> int:
    """The memory the forward pass stores for reverse mode: `max_steps` copies of `state`."""
    return max_steps * sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(state))


def stored_while_loop(cond, step, state, buffers: dict, max_steps: int):
    """Run `state = step(state)` while `cond(state)`, at most `max_steps` times, writing the
    rows each step returns into `buffers`; reverse-mode differentiable.

    - `cond(state) -> bool`.
    - `step(state) -> (state, rows, index, pred)`: `rows` a dict with the keys of
      `buffers`, written at `index` where `pred` (a row of a step with `pred` false is left
      as it was). A buffer row is written by at most one step with `pred` true, and never
      read by the step (the contract of equinox's loop buffers).

    Returns `(state, buffers)`."""
    state = jax.tree.map(jnp.asarray, state)
    step_fn, step_consts = _convert(step, state)
    cond_fn, cond_consts = _convert(cond, state)
    cond_consts = [lax.stop_gradient(c) for c in cond_consts]
    floats = {name: _is_float(buf) for name, buf in buffers.items()}

    def forward(state, buffers, consts, cond_consts, step=None, stored=()):
        # `step(consts, state) -> (state, rows, index, pred, stored)`: what it returns
        # besides the step is stored at each iteration's row of `stored`.
        def body(carry):
            k, state, buffers, stored = carry
            if step is None:
                new, rows, index, pred = step_fn(consts, state)
            else:
                new, rows, index, pred, values = step(consts, state)
                stored = [s.at[k].set(x) for s, x in zip(stored, values)]
            buffers = {
                name: buf.at[index].set(jnp.where(pred, rows[name], buf[index]))
                for name, buf in buffers.items()
            }
            return k + 1, new, buffers, stored

        init = (jnp.zeros((), jnp.int32), state, buffers, list(stored))
        k, state, buffers, stored = lax.while_loop(lambda c: cond_fn(cond_consts, c[1]), body, init)
        return (state, buffers), (k, stored)

    box = {}  # what the backward pass needs of the forward pass's trace (not arrays)

    @jax.custom_vjp
    def loop(state, buffers, consts, cond_consts):
        return forward(state, buffers, consts, cond_consts)[0]

    def loop_fwd(state, buffers, consts, cond_consts):
        # Symbolic zeros: differentiate in the perturbed constants only (the state's
        # float leaves all: a leaf unperturbed on entry may be perturbed by the steps).
        state, buffers, cond_consts = jax.tree.map(lambda p: p.value, (state, buffers, cond_consts))
        diff_consts = [_is_float(c.value) and bool(c.perturbed) for c in consts]
        consts = [c.value for c in consts]
        lin = _Linearised(step_fn, consts, diff_consts, floats, state, residuals=True)
        box["lin"] = lin
        if lin.stored_bytes * max_steps <= STORE_BUDGET_BYTES:
            stored = lin.empty(max_steps)
            out, (k, stored) = forward(state, buffers, consts, cond_consts, lin.step, stored)
            return out, (k, stored, consts)
        # Residuals too large: store the states, and linearise each step again.
        box["lin"] = _Linearised(step_fn, consts, diff_consts, floats, state, residuals=False)

        def store_state(consts, state):
            return (*step_fn(consts, state), jax.tree.leaves(state))

        empty = [jnp.zeros((max_steps,) + x.shape, x.dtype) for x in jax.tree.leaves(state)]
        out, (k, stored) = forward(state, buffers, consts, cond_consts, store_state, empty)
        return out, (k, stored, consts)

    def loop_bwd(res, ct):
        k, stored, consts = res
        lin = box["lin"]
        lin.consts = consts  # this trace's values, not the forward pass's
        ct = jax.tree.map(instantiate_zero, ct, is_leaf=is_symbolic_zero)
        ct_state, ct_buffers = ct
        ct_state0, ct_buffers0, ct_consts = _reverse(lin, k, stored, ct_state, ct_buffers)
        return ct_state0, ct_buffers0, ct_consts, [None] * len(cond_consts)

    loop.defvjp(loop_fwd, loop_bwd, symbolic_zeros=True)
    return loop(state, buffers, step_consts, cond_consts)


def is_symbolic_zero(x) -> bool:
    return isinstance(x, jax.custom_derivatives.SymbolicZero)


def instantiate_zero(x):
    """A symbolic zero cotangent as an array (float0 for integer leaves); other leaves as
    they are. Also used by the solve boundary's VJP (`nivpjax._cache`)."""
    if is_symbolic_zero(x):
        if x.aval.dtype == jax.dtypes.float0:
            return np.zeros(x.aval.shape, x.aval.dtype)
        return jnp.zeros(x.aval.shape, x.aval.dtype)
    return x


class _Linearised:
    """The step split into what reverse mode differentiates (float leaves of the state and
    of the constants) and the rest, and its VJP: from the step's residuals stored by the
    forward pass (`step`, `vjp_from_residuals`), or by linearising at a stored state
    (`vjp_at_state`)."""

    def __init__(self, step_fn, consts, diff_consts, floats, state, residuals: bool):
        self.step_fn = step_fn
        self.consts = consts
        self.diff_consts = diff_consts
        self.float_bufs = [name for name, is_float in floats.items() if is_float]
        leaves, self.treedef = jax.tree.flatten(state)
        self.is_diff = [_is_float(x) for x in leaves]
        if not residuals:  # linearised at the stored states
            self.vjp_at = self.vjp_at_state
            return
        self.vjp_at = self.vjp_from_residuals
        # The forward step with its VJP's residuals, traced once: residuals that are
        # constants of the loop (the step's constants, literals) are not stored.
        n_consts = len(consts)
        closed, shapes = jax.make_jaxpr(lambda c, x: self._with_vjp(c, x), return_shape=True)(
            list(consts), leaves
        )
        self.out_tree = jax.tree.structure(shapes)
        n_res = len(jax.tree.leaves(shapes[-1]))
        outvars = closed.jaxpr.outvars
        res_vars = outvars[len(outvars) - n_res :]
        const_index = {id(v): i for i, v in enumerate(closed.jaxpr.invars[:n_consts])}
        closed_consts = {id(v): c for v, c in zip(closed.jaxpr.constvars, closed.consts)}
        self.res_source = []  # per residual: ("const", i), ("value", x) or ("stored", j)
        self.res_avals = []
        for v in res_vars:
            if isinstance(v, jax.extend.core.Literal):
                self.res_source.append(("value", v.val))
            elif id(v) in const_index:
                self.res_source.append(("const", const_index[id(v)]))
            elif id(v) in closed_consts:
                self.res_source.append(("value", closed_consts[id(v)]))
            else:
                self.res_source.append(("stored", len(self.res_avals)))
                self.res_avals.append(v.aval)
        self.closed = closed
        self.stored_bytes = sum(a.size * a.dtype.itemsize for a in self.res_avals)
        self.packing = _Packing(self.res_avals)

    def _split_step(self, consts, leaves):
        # (x, c) -> ((new float leaves, float rows), (other new leaves, other rows, index,
        # pred)), for `jax.vjp` with `has_aux`.
        is_diff = [_is_float(x) for x in leaves]

        def diff_step(x, c):
            state = jax.tree.unflatten(self.treedef, _merge(is_diff, x, leaves))
            new, rows, index, pred = self.step_fn(_merge(self.diff_consts, c, consts), state)
            new_leaves = jax.tree.leaves(new)
            new_diff = [y for y, d in zip(new_leaves, is_diff) if d]
            new_rest = [y for y, d in zip(new_leaves, is_diff) if not d]
            rows_diff = {n: rows[n] for n in self.float_bufs}
            rows_rest = {n: r for n, r in rows.items() if n not in self.float_bufs}
            return (new_diff, rows_diff), (new_rest, rows_rest, index, pred)

        x = [v for v, d in zip(leaves, is_diff) if d]
        c = [v for v, d in zip(consts, self.diff_consts) if d]
        return diff_step, x, c, is_diff

    def _with_vjp(self, consts, leaves):
        diff_step, x, c, is_diff = self._split_step(consts, leaves)
        (new_diff, rows_diff), vjp_fn, aux = jax.vjp(diff_step, x, c, has_aux=True)
        new_rest, rows_rest, index, pred = aux
        new = jax.tree.unflatten(
            self.treedef, _merge(is_diff, new_diff, _spread(is_diff, new_rest))
        )
        residuals, self.vjp_tree = jax.tree.flatten(vjp_fn)
        return new, {**rows_diff, **rows_rest}, index, pred, residuals

    def empty(self, max_steps):
        # Each iteration's row index and predicate, then its stored residuals.
        first = [jnp.zeros((max_steps,), jnp.int32), jnp.zeros((max_steps,), bool)]
        return first + self.packing.empty(max_steps)

    def step(self, consts, state):
        """The step and the residuals of its VJP that must be stored."""
        fun = jax.extend.core.jaxpr_as_fun(self.closed)
        out = fun(*consts, *jax.tree.leaves(state))
        new, rows, index, pred, residuals = jax.tree.unflatten(self.out_tree, out)
        stored = [r for r, (kind, _) in zip(residuals, self.res_source) if kind == "stored"]
        return new, rows, index, pred, [index, pred, *self.packing.pack(stored)]

    def vjp_from_residuals(self, stored, k):
        index, pred, *rows = [lax.dynamic_index_in_dim(s, k, keepdims=False) for s in stored]
        stored = self.packing.unpack(rows)
        residuals = []
        for kind, where in self.res_source:
            if kind == "stored":
                residuals.append(stored[where])
            elif kind == "const":
                residuals.append(self.consts[where])
            else:
                residuals.append(where)
        return jax.tree.unflatten(self.vjp_tree, residuals), (index, pred)

    def vjp_at_state(self, stored, k):
        leaves = [lax.dynamic_index_in_dim(s, k, keepdims=False) for s in stored]
        diff_step, x, c, _ = self._split_step(self.consts, leaves)
        _, vjp_fn, (_, _, index, pred) = jax.vjp(diff_step, x, c, has_aux=True)
        return vjp_fn, (index, pred)


class _Packing:
    """The stored residuals of a step as one row per dtype: a step's VJP has hundreds of
    residuals (the relay's, about 370), and a row each cost a dynamic update in every
    forward iteration and a dynamic read in every backward one (4 600 of the 14 500 traced
    operations of the relay's gradient). Packing and unpacking are exact."""

    def __init__(self, avals):
        self.sizes = {}  # dtype -> the row's length
        self.layout = []  # per residual: (dtype, offset, size, shape)
        for a in avals:
            dtype = jnp.dtype(a.dtype)
            offset = self.sizes.get(dtype, 0)
            self.layout.append((dtype, offset, a.size, a.shape))
            self.sizes[dtype] = offset + a.size

    def empty(self, max_steps):
        return [jnp.zeros((max_steps, n), dtype) for dtype, n in self.sizes.items()]

    def pack(self, values):
        parts = {dtype: [] for dtype in self.sizes}
        for (dtype, *_), v in zip(self.layout, values):
            parts[dtype].append(jnp.ravel(jnp.asarray(v, dtype)))
        return [jnp.concatenate(p) for p in parts.values()]

    def unpack(self, rows):
        rows = dict(zip(self.sizes, rows))
        return [
            lax.slice_in_dim(rows[dtype], offset, offset + size).reshape(shape)
            for dtype, offset, size, shape in self.layout
        ]


def _reverse(lin, count, stored, ct_state, ct_buffers):
    # Walk back from the last iteration: at each, the VJP of the step with the cotangent
    # of its output state and of the rows it wrote (read, then cleared, at its row where
    # it wrote one). The constants' cotangents sum over the iterations.
    consts = lin.consts
    leaves_ct = jax.tree.leaves(ct_state)
    is_diff = lin.is_diff
    diff_consts = lin.diff_consts
    ct_state = [c for c, d in zip(leaves_ct, is_diff) if d]
    ct_bufs = {name: ct_buffers[name] for name in lin.float_bufs}
    ct_consts = [jnp.zeros_like(c) for c, d in zip(consts, diff_consts) if d]

    def body(carry):
        k, ct_state, ct_bufs, ct_consts = carry
        k = k - 1
        vjp_fn, (index, pred) = lin.vjp_at(stored, k)
        ct_rows = {}
        for name in lin.float_bufs:
            row = ct_bufs[name][index]
            ct_rows[name] = jnp.where(pred, row, jnp.zeros_like(row))
            ct_bufs[name] = ct_bufs[name].at[index].set(jnp.where(pred, jnp.zeros_like(row), row))
        ct_x, ct_c = vjp_fn((ct_state, ct_rows))
        ct_consts = [a + b for a, b in zip(ct_consts, ct_c)]
        return k, list(ct_x), ct_bufs, ct_consts

    init = (count, ct_state, ct_bufs, ct_consts)
    _, ct_state, ct_bufs, ct_consts = lax.while_loop(lambda c: c[0] > 0, body, init)
    ct_state = jax.tree.unflatten(lin.treedef, _merge(is_diff, ct_state, [None] * len(is_diff)))
    ct_buffers = {name: ct_bufs.get(name) for name in ct_buffers}
    return ct_state, ct_buffers, _merge(diff_consts, ct_consts, [None] * len(consts))


def _merge(mask, chosen, others):
    # `chosen` where `mask`, `others` elsewhere (`chosen` holds only the masked entries).
    it = iter(chosen)
    return [next(it) if m else o for m, o in zip(mask, others)]


def _spread(mask, chosen):
    # The entries of `chosen` at the positions where `mask` is false, `None` elsewhere.
    it = iter(chosen)
    return [None if m else next(it) for m in mask]


def _is_float(x) -> bool:
    return jnp.issubdtype(jnp.result_type(x), jnp.inexact)


def _convert(fn, state):
    # `fn(state)` as `converted(consts, state)`, with every closed-over value in `consts`.
    flat, tree = jax.tree.flatten(state)
    closed, shapes = jax.make_jaxpr(
        lambda *leaves: fn(jax.tree.unflatten(tree, leaves)), return_shape=True
    )(*flat)
    out_tree = jax.tree.structure(shapes)
    jaxpr = closed.jaxpr

    def converted(consts, state):
        fun = jax.extend.core.jaxpr_as_fun(jax.extend.core.ClosedJaxpr(jaxpr, list(consts)))
        return jax.tree.unflatten(out_tree, fun(*jax.tree.leaves(state)))

    return converted, list(closed.consts)
