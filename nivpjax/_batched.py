"""`solve_batched`: many members of one model, vmapped, ordered, chunked and sharded across
devices (and processes). Built on [`nivpjax.solve`][]; the loop itself knows nothing of
batches."""

from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ._cache import CachedJit
from ._results import RESULTS
from ._saveat import SaveAt
from ._solution import Solution
from ._solve import _IN_GRAPH_CHECKS, SolveError, solve
from ._validate import check_times


class _Frozen:
    """A concrete NumPy array as static configuration (hashed by value): the mass matrix
    and equation rows must stay concrete inside the batched program."""

    __slots__ = ("array",)

    def __init__(self, array):
        self.array = np.asarray(array)

    def __hash__(self):
        return hash((self.array.shape, self.array.dtype.str, self.array.tobytes()))

    def __eq__(self, other):
        return isinstance(other, _Frozen) and np.array_equal(self.array, other.array)


_CONCRETE = ("mass_matrix", "equation_rows")


def _batched_impl(vector_field, t0, t1, y0, args, args_axes, kwargs, mesh):
    # `mesh` is static: one program per device set. With a mesh, each device runs the
    # vmapped loop of its own share of the batch (`shard_map`): it stops when its slowest
    # member is done, and no iteration waits for the other devices.
    kwargs = {k: (v.array if isinstance(v, _Frozen) else v) for k, v in kwargs.items()}

    def one(y, a):
        return solve(vector_field, t0, t1, y, a, throw=False, **kwargs)

    def share(y, a):
        return jax.vmap(one, in_axes=(0, args_axes))(y, a)

    if mesh is not None:
        share = jax.shard_map(
            share,
            mesh=mesh,
            in_specs=(PartitionSpec("batch"), _specs(args_axes)),
            out_specs=PartitionSpec("batch"),
            check_vma=False,
        )
    token = _IN_GRAPH_CHECKS.set(False)
    try:
        return share(y0, args)
    finally:
        _IN_GRAPH_CHECKS.reset(token)


def _spec(ax):
    return PartitionSpec() if ax is None else PartitionSpec(*([None] * ax + ["batch"]))


def _specs(axes):
    return jax.tree.map(_spec, axes, is_leaf=_none)


_batched_jit = CachedJit(_batched_impl)


def _batch_size(y0, args, args_axes):
    sizes = set()
    if y0.ndim == 2:
        sizes.add(y0.shape[0])
    leaves = jax.tree.leaves(jax.tree.map(lambda ax, a: (ax, a), args_axes, args, is_leaf=_none))
    for ax, a in zip(leaves[::2], leaves[1::2]):
        if ax is not None:
            sizes.add(np.shape(a)[ax])
    if len(sizes) != 1:
        raise ValueError(
            "`y0` (shape (batch, n)) and the batched leaves of `args` must share one batch "
            f"size, got sizes {sorted(sizes) or 'none (nothing is batched)'}."
        )
    return sizes.pop()


def _none(x):
    return x is None


def _full_axes(axes, tree):
    """`axes` (a prefix of `tree`, as `jax.vmap`'s `in_axes`) expanded to one per leaf."""
    return jax.tree.map(lambda ax, sub: jax.tree.map(lambda _: ax, sub), axes, tree, is_leaf=_none)


def _take(tree, idx, axes):
    return jax.tree.map(
        lambda ax, a: a if ax is None else np.take(np.asarray(a), idx, axis=ax),
        axes,
        tree,
        is_leaf=_none,
    )


def _order(cost, y0, args, args_axes, size):
    if cost is None:
        return np.arange(size)
    if callable(cost):
        cost = jax.vmap(cost, in_axes=(0, args_axes))(y0, args)
    cost = np.asarray(cost, dtype=float)
    if cost.shape != (size,):
        raise ValueError(
            f"`cost` must give one value per member, shape ({size},), got {cost.shape}."
        )
    return np.argsort(cost, kind="stable")


def _mesh(devices):
    devices = jax.devices() if devices is None else list(devices)
    if not devices:
        raise ValueError("`devices` must name at least one device.")
    return Mesh(np.asarray(devices), ("batch",))


def _shard(tree, axes, mesh):
    """`tree` as global arrays over `mesh`, batched leaves split along their batch axis.
    Each process builds only the shards of its own devices (from the full host array every
    process holds), so the same call works in one process and across several."""
    if mesh is None:
        return tree

    def put(ax, a):
        a = np.asarray(a)
        sharding = NamedSharding(mesh, _spec(ax))
        return jax.make_array_from_callback(a.shape, sharding, lambda index: a[index])

    return jax.tree.map(put, axes, tree, is_leaf=_none)


def _to_host(sol):
    """The whole result on the host of every process (an all-gather across processes when
    the result lives on devices of several)."""
    if jax.process_count() == 1:
        return jax.tree.map(np.asarray, sol)
    return multihost_utils.process_allgather(sol, tiled=True)


def solve_batched(
    vector_field,
    t0,
    t1,
    y0,
    args: Any = None,
    *,
    args_axes: Any = 0,
    cost=None,
    chunk_size: int | None = None,
    devices=None,
    saveat: SaveAt | None = None,
    throw: bool = False,
    **kwargs,
) -> Solution:
    r"""Solve a batch of members of one model: `y0` and/or `args` carry a leading batch axis.

    The members run in lock step under `jax.vmap`: each loop iteration attempts a step of
    every unfinished member, so a batch costs as much as its slowest member times its size.
    Two levers cut that waste: `cost` orders the members so that those needing similar step
    counts run together, and `chunk_size` runs the ordered batch in chunks of that many
    members, one after another, through one compiled program. Each chunk is split along
    the batch axis over `devices` (default: every device JAX sees, across all processes
    after `jax.distributed.initialize()`) with a 1-D `jax.sharding.Mesh` named `"batch"`,
    and each device runs the loop of its own share (`jax.shard_map`): a device stops when
    its own slowest member is done. Results are identical to an unsharded run.

    By default only the final state and the counters are kept (`saveat=SaveAt()`): a
    sweep's members then carry no buffers of `max_steps` rows. Pass `t_eval` for states
    at output times, or `saveat=nj.SaveAt(steps=True)` for every step.

    **Arguments:**

    - `vector_field`, `t0`, `t1`: as for [`nivpjax.solve`][] (shared by all members).
    - `y0`: shape `(batch, n)`, or `(n,)` for one initial state shared by all members.
    - `args`: a pytree; leaves batched along `args_axes`.
    - `args_axes`: as `jax.vmap`'s `in_axes` for `args` (a prefix pytree of ints or `None`;
      default 0: every leaf batched along its first axis).
    - `cost`: `None` (keep the order), an array of shape `(batch,)`, or a function
      `cost(y0_i, args_i) -> scalar` (vmapped): members are sorted by increasing cost
      before chunking. Any cheap proxy of the step count works: a parameter that drives the
      number of events (restitution, friction, amplitude), or the step count of an earlier
      sweep.
    - `chunk_size`: members per chunk (rounded up to a multiple of the number of devices;
      default: the whole batch at once). The last chunk is padded by repeating a member.
    - `devices`: the devices to shard over (default `jax.devices()`: with several
      processes, the devices of all of them; every process makes the same call with the
      same arguments and builds only its own devices' shards).
    - `saveat`: a [`nivpjax.SaveAt`][]; default `SaveAt()` (final state only, plus the
      states at `t_eval` if given).
    - `throw`: raise [`nivpjax.SolveError`][] if any member failed. Default `False`: the
      result code of each member is in `Solution.result`.
    - `kwargs`: any other keyword argument of [`nivpjax.solve`][] (`projector`, `stepper`,
      `controller`, `mass_matrix`, `t_eval`, `max_steps`, ...), shared by all members.

    **Returns:** a [`nivpjax.Solution`][] whose every field has a leading batch axis, in the
    members' original order (on the host of every process when the run spans several).
    """
    if "progress" in kwargs:
        raise ValueError("`progress` is not supported by solve_batched.")
    kwargs["saveat"] = SaveAt() if saveat is None else saveat
    y0 = np.asarray(y0)
    args_axes = _full_axes(args_axes, args)
    if y0.ndim not in (1, 2):
        raise ValueError(f"`y0` must have shape (batch, n) or (n,), got {y0.shape}.")
    if y0.ndim == 1:
        size = _batch_size(y0, args, args_axes)
        y0 = np.broadcast_to(y0, (size,) + y0.shape)
    else:
        size = _batch_size(y0, args, args_axes)
    check_times(t0, t1)
    if not np.all(np.isfinite(y0)):
        raise ValueError("`y0` contains NaN or inf.")
    if chunk_size is not None and (not isinstance(chunk_size, int) or chunk_size < 1):
        raise ValueError(f"`chunk_size` must be a positive int or None, got {chunk_size!r}.")
    for name in _CONCRETE:
        if kwargs.get(name) is not None:
            kwargs[name] = _Frozen(kwargs[name])
    mesh = _mesh(devices)
    n_dev = mesh.devices.size
    if n_dev == 1:
        # One device: plain arrays. (A one-device NamedSharding made jax 0.10 reuse an
        # executable with the wrong argument count on the second chunk.)
        mesh = None
    chunk = size if chunk_size is None else min(chunk_size, size)
    chunk = -(-chunk // n_dev) * n_dev
    order = _order(cost, y0, args, args_axes, size)
    parts = []
    for start in range(0, size, chunk):
        idx = order[start : start + chunk]
        idx = np.concatenate([idx, np.full(chunk - idx.size, idx[-1])])
        y_c = _shard(np.take(y0, idx, axis=0), 0, mesh)
        a_c = _shard(_take(args, idx, args_axes), args_axes, mesh)
        parts.append(_batched_jit(vector_field, t0, t1, y_c, a_c, args_axes, kwargs, mesh))
    in_place = len(parts) == 1 and chunk == size and np.array_equal(order, np.arange(size))
    if in_place and jax.process_count() == 1:
        sol = parts[0]  # kept on the devices, sharded
    else:  # gathered on the host, in the original order
        parts = [_to_host(p) for p in parts]
        inverse = np.empty(size, np.int64)
        inverse[order] = np.arange(size)
        sol = jax.tree.map(lambda *xs: np.concatenate(xs)[:size][inverse], *parts)
    if throw:
        failed = np.flatnonzero(np.asarray(sol.result._value) != RESULTS.successful._value)
        if failed.size:
            raise SolveError(
                f"{failed.size} of {size} members failed (indices {failed[:10].tolist()}"
                f"{'...' if failed.size > 10 else ''}); pass throw=False and inspect "
                "`Solution.result` per member."
            )
    return sol


def lockstep_waste(sol: Solution, chunk_size: int | None = None, cost=None) -> float:
    """The fraction of attempted member-steps that lock-step batching wasted in a
    [`nivpjax.solve_batched`][] run with the same `chunk_size` and `cost` (array form):
    $1 - \\sum_i a_i / \\sum_c |c| \\max_{i \\in c} a_i$, $a_i$ the attempts of member $i$
    and $c$ the chunks (ignoring the padding of the last chunk)."""
    attempts = np.asarray(sol.n_accepted + sol.n_rejected)
    size = attempts.shape[0]
    order = np.arange(size) if cost is None else np.argsort(np.asarray(cost), kind="stable")
    chunk = size if chunk_size is None else chunk_size
    ran = sum(
        len(c) * c.max() for c in (attempts[order[s : s + chunk]] for s in range(0, size, chunk))
    )
    return float(1.0 - attempts.sum() / max(ran, 1))
