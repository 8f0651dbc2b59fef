"""Composition of projectors over index blocks of the state."""

import jax.numpy as jnp
import numpy as np

from .base import AbstractProjector, ProjectionContext


class BlockProjector(AbstractProjector):
    r"""Apply different projectors to different index blocks of the state; components in no
    block pass through unchanged (the identity).

    `blocks` is a sequence of `(indices, projector)` pairs with disjoint index sets. Each
    projector receives `z[indices]` and the context with `rho` restricted to the block (the
    states in the context stay whole, so its bounds may depend on any component) and returns
    a vector of the same length.

    This is the basis for a model that pays only for the effects it has: an empty
    `BlockProjector` compiles to nothing at all, and each block adds exactly its own kernel.
    The generalised Jacobian is block diagonal, each block taking its projector's element.
    """

    blocks: tuple[tuple[tuple[int, ...], AbstractProjector], ...]

    def __init__(self, blocks):
        if isinstance(blocks, AbstractProjector) or not isinstance(blocks, (list, tuple)):
            raise TypeError(
                "`blocks` must be a list of `(indices, projector)` pairs, got "
                f"{type(blocks).__name__}."
            )
        seen: set[int] = set()
        out = []
        for entry in blocks:
            try:
                indices, projector = entry
            except (TypeError, ValueError):
                raise TypeError(
                    f"`blocks` must be a sequence of `(indices, projector)` pairs, got {entry!r}."
                ) from None
            arr = np.atleast_1d(np.asarray(indices))
            integer = np.issubdtype(arr.dtype, np.integer) and arr.dtype != np.bool_
            if arr.ndim != 1 or not (integer or arr.size == 0):
                raise TypeError(
                    f"block indices must be integers, got {indices!r} (dtype {arr.dtype})."
                )
            idx = tuple(int(i) for i in arr)
            if len(set(idx)) != len(idx):
                raise ValueError(f"block indices repeat within a block: {list(idx)}.")
            if not isinstance(projector, AbstractProjector):
                raise TypeError(
                    f"each block's projector must be an AbstractProjector, got {projector!r}."
                )
            overlap = seen.intersection(idx)
            if overlap:
                raise ValueError(f"block indices overlap at {sorted(overlap)}.")
            seen.update(idx)
            out.append((idx, projector))
        self.blocks = tuple(out)

    def __call__(self, z, ctx: ProjectionContext):
        z = jnp.asarray(z)
        out = z
        for indices, projector in self.blocks:
            idx = np.asarray(indices)
            out = out.at[idx].set(projector(z[idx], self._sub(ctx, indices, z.shape)))
        return out

    def validate(self, n: int) -> None:
        for indices, projector in self.blocks:
            bad = [i for i in indices if not -n <= i < n]
            if bad:
                raise ValueError(
                    f"BlockProjector indices {bad} are out of range for a state of size {n}."
                )

    @staticmethod
    def _sub(ctx: ProjectionContext, indices, shape):
        rho = jnp.broadcast_to(ctx.rho, shape)[np.asarray(indices)]
        return ProjectionContext(
            t=ctx.t,
            h=ctx.h,
            y_prev=ctx.y_prev,
            y_iter=ctx.y_iter,
            rho=rho,
            args=ctx.args,
            block=indices,
            rate=ctx.rate,
            rate_at=ctx.rate_at,
            start_rate=ctx.start_rate,
            end_rate=ctx.end_rate,
            y_next=ctx.y_next,
            next_rate=ctx.next_rate,
            after_end=ctx.after_end,
            tangent=ctx.tangent,
            law=ctx.law,
            tolerance=ctx.tolerance,
            violation_scale=ctx.violation_scale,
        )

    def violation(self, ctx: ProjectionContext):
        out = jnp.zeros((), ctx.y_iter.dtype)
        for indices, projector in self.blocks:
            out = jnp.maximum(out, projector.violation(self._sub(ctx, indices, ctx.y_iter.shape)))
        return out

    def next_event(self, ctx: ProjectionContext):
        """The earliest predicted event of the blocks."""
        out = jnp.full((), jnp.inf, ctx.y_iter.dtype)
        for indices, projector in self.blocks:
            sub = self._sub(ctx, indices, ctx.y_iter.shape)
            out = jnp.minimum(out, projector.next_event(sub))
        return out

    def initial_violation(self, ctx: ProjectionContext):
        out = jnp.zeros((), ctx.y_prev.dtype)
        for indices, projector in self.blocks:
            sub = self._sub(ctx, indices, ctx.y_iter.shape)
            out = jnp.maximum(out, projector.initial_violation(sub))
        return out

    @property
    def has_event_time(self) -> bool:
        return any(projector.has_event_time for _, projector in self.blocks)

    def event_time(self, ctx: ProjectionContext):
        """The earliest event of the blocks."""
        tau = jnp.full((), jnp.inf, ctx.y_prev.dtype)
        found = jnp.zeros((), bool)
        for indices, projector in self.blocks:
            tau_b, found_b = projector.event_time(self._sub(ctx, indices, ctx.y_iter.shape))
            first = found_b & (~found | (tau_b < tau))
            tau = jnp.where(first, tau_b, tau)
            found = found | found_b
        return jnp.where(found, tau, 0.0), found

    @property
    def has_start_selection(self) -> bool:
        return any(projector.has_start_selection for _, projector in self.blocks)

    def start_selection(self, ctx: ProjectionContext):
        """Each block's start selection on its own components."""
        out = ctx.restrict(ctx.y_prev)
        skipped = jnp.zeros((), ctx.y_prev.dtype)
        for indices, projector in self.blocks:
            if projector.has_start_selection:
                sub = self._sub(ctx, indices, ctx.y_prev.shape)
                w, skipped_b = projector.start_selection(sub)
                out = out.at[np.asarray(indices)].set(w)
                # Ties go to the block (not `maximum`, which halves the derivative of two
                # equal values: a switch on the surface skips a time of 0 with a derivative).
                skipped = jnp.where(skipped_b >= skipped, skipped_b, skipped)
        return out, skipped

    @property
    def has_switch_shift(self) -> bool:
        return any(projector.has_switch_shift for _, projector in self.blocks)

    def switch_shift(self, ctx: ProjectionContext):
        """Each block's switch shifts on its own components."""
        base = end = jnp.zeros_like(ctx.rho)
        found = jnp.zeros((), bool)
        for indices, projector in self.blocks:
            if projector.has_switch_shift:
                idx = np.asarray(indices)
                b, e, found_b = projector.switch_shift(self._sub(ctx, indices, ctx.rho.shape))
                base = base.at[idx].set(b)
                end = end.at[idx].set(e)
                found = found | found_b
        return base, end, found

    @property
    def has_arrests(self) -> bool:
        return any(projector.has_arrests for _, projector in self.blocks)

    def arrest_error(self, ctx: ProjectionContext):
        """Each block's arrested rows and their errors on its own components."""
        arrested = jnp.zeros(ctx.rho.shape, bool)
        error = jnp.zeros(ctx.rho.shape, ctx.y_iter.dtype)
        for indices, projector in self.blocks:
            if projector.has_arrests:
                idx = np.asarray(indices)
                a, e = projector.arrest_error(self._sub(ctx, indices, ctx.rho.shape))
                arrested = arrested.at[idx].set(a)
                error = error.at[idx].set(e)
        return arrested, error

    def acts_on(self, n: int) -> np.ndarray:
        """The rows of the blocks whose projectors may move them."""
        return self._rows(n, lambda projector, m: projector.acts_on(m))

    def weighed_rows(self, n: int) -> np.ndarray:
        """The rows of the blocks whose projectors weigh their reactions."""
        return self._rows(n, lambda projector, m: projector.weighed_rows(m))

    def _rows(self, n, mask_of):
        # A static row mask of size n from each block's own mask of its rows.
        mask = np.zeros(n, bool)
        for indices, projector in self.blocks:
            idx = np.asarray(indices)
            mask[idx] = mask_of(projector, idx.size)
        return mask

    @property
    def has_kinks(self) -> bool:
        return any(projector.has_kinks for _, projector in self.blocks)

    def early_kinks(self, ctx: ProjectionContext):
        """Each block's early kink crossings on its own components."""
        out = jnp.zeros(ctx.restrict(ctx.y_prev).shape, bool)
        for indices, projector in self.blocks:
            if projector.has_kinks:
                sub = self._sub(ctx, indices, ctx.y_iter.shape)
                out = out.at[np.asarray(indices)].set(projector.early_kinks(sub))
        return out

    def impulsive(self, ctx: ProjectionContext):
        out = jnp.zeros((), bool)
        for indices, projector in self.blocks:
            out = out | projector.impulsive(self._sub(ctx, indices, ctx.y_iter.shape))
        return out

    def impact(self, ctx: ProjectionContext):
        out = ctx.restrict(ctx.y_prev)
        for indices, projector in self.blocks:
            if projector.has_event_time:
                sub = self._sub(ctx, indices, ctx.y_prev.shape)
                out = out.at[np.asarray(indices)].set(projector.impact(sub))
        return out

    def switched(self, ctx: ProjectionContext):
        out = jnp.zeros((), bool)
        for indices, projector in self.blocks:
            out = out | projector.switched(self._sub(ctx, indices, ctx.y_iter.shape))
        return out
