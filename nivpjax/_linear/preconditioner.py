r"""Preconditioners for the Krylov solve, built from Jacobian-vector products of the
linearised natural map."""

import abc
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .. import _linalg


Apply = Callable[[Array], Array]


class AbstractPreconditioner(eqx.Module):
    r"""Builds an approximate inverse $M \approx G'(y)^{-1}$ from the linear map
    $v \mapsto G'(y)\,v$, once per Newton iteration (and once per implicit-function
    solve). Subclass it to pass a preconditioner of your own."""

    @abc.abstractmethod
    def build(self, matvec: Apply, n: int, dtype) -> tuple[Apply, Apply]:
        r"""`(apply, apply_transpose)`: $v \mapsto M v$ and $v \mapsto M^\top v$, linear."""


class BlockJacobi(AbstractPreconditioner):
    r"""Block-Jacobi: $M$ inverts the diagonal blocks of $G'(y)$ over a partition of the
    unknowns into blocks of equal size $k$ (the diagonal, $k = 1$, by default; the cells
    of a model, e.g. the position and velocity of each block of a chain, otherwise).

    The blocks are read exactly from products of $G'(y)$ with probe vectors: probe
    $(c, s)$ is the sum of the $s$-th unit vectors of every block of colour $c$. That
    costs $k$ products per colour; it is exact when no two blocks of one colour are
    coupled (no entry of $G'$ in a row of one and a column of the other), which the
    caller asserts by passing `colors`. Without `colors` every block has its own colour:
    exact for any Jacobian, at $n$ products (as many as forming $G'$), so pass a colouring
    whenever the coupling is sparse. A block that is singular (not finite when inverted)
    is left unpreconditioned (identity).

    **Arguments:**

    - `blocks`: integer array of shape `(number of blocks, k)`: the unknowns of each
      block, every unknown in exactly one block; by default each unknown is its own block.
    - `colors`: integer array of shape `(number of blocks,)`, a colour per block (see
      above); by default all distinct.
    - `batch`: products evaluated together (vectorised) when probing.
    """

    # Static, as hashable tuples (they set the probes: the compiled program's shape).
    blocks: tuple[tuple[int, ...], ...] | None = eqx.field(static=True, default=None)
    colors: tuple[int, ...] | None = eqx.field(static=True, default=None)
    batch: int = eqx.field(static=True, default=32)

    def __init__(self, blocks=None, colors=None, batch=32):
        if blocks is not None:
            blocks = np.asarray(blocks)
            if blocks.ndim == 1:
                blocks = blocks[:, None]
            if blocks.ndim != 2 or not np.issubdtype(blocks.dtype, np.integer):
                raise ValueError(
                    "`blocks` must be an integer array of shape (number of blocks, k), got "
                    f"shape {blocks.shape} and dtype {blocks.dtype}."
                )
        if colors is not None:
            colors = np.asarray(colors)
            n_blocks = None if blocks is None else blocks.shape[0]
            if colors.ndim != 1 or not np.issubdtype(colors.dtype, np.integer):
                raise ValueError(f"`colors` must be a 1-D integer array, got {colors!r}.")
            if n_blocks is not None and colors.shape[0] != n_blocks:
                raise ValueError(
                    f"`colors` needs one colour per block ({n_blocks}), got {colors.shape[0]}."
                )
        if not (isinstance(batch, int) and batch >= 1):
            raise ValueError(f"`batch` must be a positive int, got {batch!r}.")
        self.blocks = None if blocks is None else tuple(tuple(int(i) for i in b) for b in blocks)
        self.colors = None if colors is None else tuple(int(c) for c in colors)
        self.batch = batch

    def _layout(self, n):
        blocks = np.arange(n)[:, None] if self.blocks is None else np.asarray(self.blocks)
        if np.sort(blocks.ravel()).tolist() != list(range(n)):
            raise ValueError(
                f"BlockJacobi `blocks` must hold each of the {n} unknowns exactly once, got "
                f"{blocks.size} entries."
            )
        colors = np.arange(blocks.shape[0]) if self.colors is None else np.asarray(self.colors)
        if colors.shape[0] != blocks.shape[0]:
            raise ValueError(
                f"`colors` needs one colour per block ({blocks.shape[0]}), got {colors.shape[0]}."
            )
        _, colors = np.unique(colors, return_inverse=True)
        n_colors = int(colors.max()) + 1
        width = int(np.bincount(colors).max())
        members = np.full((n_colors, width), -1)  # the blocks of each colour, padded
        slot = np.zeros(blocks.shape[0], int)
        for c in range(n_colors):
            which = np.flatnonzero(colors == c)
            members[c, : which.size] = which
            slot[which] = np.arange(which.size)
        return blocks, colors, members, slot

    def build(self, matvec, n, dtype):
        blocks, colors, members, slot = self._layout(n)
        k = blocks.shape[1]
        valid = members >= 0
        cols = blocks[np.where(valid, members, 0)]  # (colours, width, k)

        def probe(c_s):
            c, s = c_s
            v = (
                jnp.zeros(n, dtype)
                .at[jnp.asarray(cols)[c, :, s]]
                .add(jnp.where(jnp.asarray(valid)[c], 1.0, 0.0).astype(dtype))
            )
            return matvec(v)[jnp.asarray(cols)[c]]  # (width, k): rows of those blocks

        c_idx, s_idx = np.meshgrid(np.arange(members.shape[0]), np.arange(k), indexing="ij")
        pairs = (jnp.asarray(c_idx.ravel()), jnp.asarray(s_idx.ravel()))
        out = jax.lax.map(probe, pairs, batch_size=self.batch)
        out = out.reshape(members.shape[0], k, members.shape[1], k)  # (c, s, slot, row)
        B = out[
            colors[:, None, None],
            np.arange(k)[None, None, :],
            slot[:, None, None],
            np.arange(k)[None, :, None],
        ]  # (block, row, column)
        inv = jax.vmap(_linalg.inverse)(B)
        usable = jnp.all(jnp.isfinite(inv), axis=(1, 2), keepdims=True)
        inv = jnp.where(usable, inv, jnp.eye(k, dtype=dtype))
        idx = jnp.asarray(blocks)

        def apply(v):
            return v.at[idx].set(jnp.einsum("brs,bs->br", inv, v[idx]))

        def apply_transpose(v):
            return v.at[idx].set(jnp.einsum("bsr,bs->br", inv, v[idx]))

        return apply, apply_transpose
