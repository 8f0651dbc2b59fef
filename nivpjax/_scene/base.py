"""A scene: smooth dynamics plus the effects it calls for, assembled into one model."""

import abc
import dataclasses
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._projector import AbstractProjector, BlockProjector, Identity


class AbstractEffect(eqx.Module):
    """One nonsmooth effect of a [`nivpjax.Scene`][].

    An effect either acts on existing states (contact on velocities, friction) and has no
    multipliers, or owns `size` multiplier components (a relay selection, a diode current,
    a saturated signal) with their algebraic rows.

    - `size`: number of multiplier components it adds (0 for state-acting effects).
    - `name`: key of its multipliers in the `multipliers` dict passed to the dynamics.
    - `blocks(n_states, offset)`: `(indices, projector)` pairs for the scene's
      [`nivpjax.BlockProjector`][]; `offset` is where its multipliers start in the state.
      Callables inside receive the full state; use `scene_state(y, n_states)` to read $x$.
    - `constraint(t, x, lam, args)`: the algebraic rows $f_{\\text{alg}}$ of its multipliers
      (the stage solves $\\lambda = P(\\lambda + \\rho f_{\\text{alg}})$).
    - `equation`: whether those rows are algebraic equations with $O(1)$ sensitivity to
      $\\lambda$ (scaled $\\rho = \\tau$) rather than multipliers entering the state with
      weight $h$ (scaled $\\rho = \\tau/h$).
    """

    name: eqx.AbstractVar[str]

    @property
    def size(self) -> int:
        return 0

    @property
    def equation(self) -> bool:
        return False

    @abc.abstractmethod
    def blocks(self, n_states: int, offset: int) -> list[tuple[Any, AbstractProjector]]: ...

    def constraint(self, t, x, lam, args):
        raise NotImplementedError(f"{type(self).__name__} has no multipliers.")

    def resolved(self, t, x, args) -> "AbstractEffect":
        """This effect with what it leaves to the data decided from the scene's initial
        time, states and parameters (a [`nivpjax.Contact`][]'s `curved=None`): the scene's
        `solve` and `sweep` call it. Default: itself."""
        return self


def scene_state(y, n_states):
    """The scene's own states $x$ (the first `n_states` components of the full state)."""
    return y[:n_states]


class OnScene(eqx.Module):
    """Adapts `fn(t, x, args)`, written for the scene's states, to the full state `y`.
    A module rather than a closure, so that equal scenes hash equally and compiled solves
    are reused."""

    fn: Callable
    n_states: int = eqx.field(static=True)

    def __call__(self, t, y, args):
        return self.fn(t, scene_state(y, self.n_states), args)


class Scene(eqx.Module):
    r"""Smooth dynamics plus a tuple of effects, assembled into the state layout, the
    descriptor matrix, the composite projector and the error mask, so that the model is
    solved with [`nivpjax.solve`][] without indexing slices by hand.

    The full state is $y = (x, \lambda_1, \lambda_2, \dots)$: the scene's `n_states`
    differential states followed by each effect's multipliers (algebraic rows, left out of
    the error norm). The dynamics see the multipliers by effect name:

    $$ A_x x' = \text{dynamics}(t, x, \text{args}, \text{multipliers}). $$

    A scene simulates only the effects it calls for: with no effects the projector is the
    identity and each stage is a plain implicit step; each effect adds exactly its own
    projector block (and multiplier rows). Effects and parameters are pytrees, so scenes can
    be `vmap`ped and differentiated over them.

    **Arguments:**

    - `dynamics`: `(t, x, args, multipliers) -> x'` (times `mass_matrix`), where
      `multipliers` maps effect names to their multiplier arrays.
    - `n_states`: the dimension of $x$.
    - `effects`: a tuple of [`nivpjax.AbstractEffect`][].
    - `mass_matrix`: the constant $A_x$ (default identity).
    """

    dynamics: Callable[..., Any]
    n_states: int = eqx.field(static=True)
    effects: tuple[AbstractEffect, ...] = ()
    mass_matrix: Any = None

    def __check_init__(self):
        names = [e.name for e in self.effects if e.size > 0]
        if len(set(names)) != len(names):
            raise ValueError(f"effects with multipliers need distinct names, got {names}.")

    @property
    def size(self) -> int:
        """Dimension of the full state $y$."""
        return self.n_states + sum(e.size for e in self.effects)

    def _offsets(self):
        offset, out = self.n_states, []
        for e in self.effects:
            out.append(offset)
            offset += e.size
        return out

    def split(self, y):
        """`(x, multipliers)` from a full state (or a trajectory of them, on the last axis)."""
        x = y[..., : self.n_states]
        multipliers = {
            e.name: y[..., o : o + e.size]
            for e, o in zip(self.effects, self._offsets())
            if e.size > 0
        }
        return x, multipliers

    def vector_field(self, t, y, args):
        x, multipliers = self.split(y)
        dx = jnp.asarray(self.dynamics(t, x, args, multipliers), y.dtype)
        rows = [dx]
        for e in self.effects:
            if e.size > 0:
                lam = multipliers[e.name]
                rows.append(jnp.asarray(e.constraint(t, x, lam, args), y.dtype).reshape(e.size))
        return jnp.concatenate(rows)

    @property
    def projector(self) -> AbstractProjector:
        blocks = []
        for e, o in zip(self.effects, self._offsets()):
            blocks.extend(e.blocks(self.n_states, o))
        return BlockProjector(blocks) if blocks else Identity()

    @property
    def full_mass_matrix(self):
        n, m = self.n_states, self.size
        if self.mass_matrix is None and m == n:
            return None
        A = np.zeros((m, m))
        A[:n, :n] = np.eye(n) if self.mass_matrix is None else np.asarray(self.mass_matrix)
        return A

    @property
    def equation_rows(self):
        rows = np.zeros(self.size, bool)
        for e, o in zip(self.effects, self._offsets()):
            if e.size > 0 and e.equation:
                rows[o : o + e.size] = True
        return rows if rows.any() else None

    def initial_state(self, x0, multipliers=None):
        """The full initial state from `x0` and optional initial multipliers (default 0;
        they are only initial guesses: the first stage computes consistent values)."""
        x0 = jnp.asarray(x0)
        parts = [x0]
        multipliers = multipliers or {}
        for e in self.effects:
            if e.size > 0:
                lam = multipliers.get(e.name, jnp.zeros(e.size, x0.dtype))
                parts.append(jnp.broadcast_to(jnp.asarray(lam, x0.dtype), (e.size,)))
        return jnp.concatenate(parts)

    def solve(self, t0, t1, x0, args=None, *, multipliers=None, **kwargs):
        """Solve the scene with [`nivpjax.solve`][]; `kwargs` are passed on (stepper,
        controller, t_eval, max_steps, throw, ...). Returns the [`nivpjax.Solution`][] of
        the full state; use `split` on `Solution.ys` for states and multipliers."""
        from .._solve import solve

        x0 = jnp.asarray(x0)
        if x0.shape != (self.n_states,):
            raise ValueError(
                f"`x0` must have shape ({self.n_states},) (the scene's n_states), got {x0.shape}."
            )
        scene = self.resolved(t0, x0, args)
        return solve(
            scene.vector_field,
            t0,
            t1,
            scene.initial_state(x0, multipliers),
            args,
            projector=scene.projector,
            mass_matrix=scene.full_mass_matrix,
            equation_rows=scene.equation_rows,
            **kwargs,
        )

    def sweep(self, t0, t1, x0, args=None, *, multipliers=None, **kwargs):
        """Solve a batch of members of the scene with [`nivpjax.solve_batched`][]: `x0` of
        shape `(batch, n_states)` or `(n_states,)`, `args` leaves batched along
        `args_axes` (default 0); `kwargs` (cost, chunk_size, devices, stepper, controller,
        ...) are passed on. Returns the batched [`nivpjax.Solution`][] of the full state."""
        from .._batched import solve_batched

        x0 = np.asarray(x0)
        if x0.shape[-1:] != (self.n_states,) or x0.ndim > 2:
            raise ValueError(
                f"`x0` must have shape (batch, {self.n_states}) or ({self.n_states},), got "
                f"{x0.shape}."
            )
        y0 = np.stack([np.asarray(self.initial_state(x, multipliers)) for x in np.atleast_2d(x0)])
        first = _first_member(args, kwargs.get("args_axes", 0))
        scene = self.resolved(t0, np.atleast_2d(x0)[0], first)
        return solve_batched(
            scene.vector_field,
            t0,
            t1,
            y0[0] if x0.ndim == 1 else y0,
            args,
            projector=scene.projector,
            mass_matrix=scene.full_mass_matrix,
            equation_rows=scene.equation_rows,
            **kwargs,
        )

    def resolved(self, t0, x0, args) -> "Scene":
        """The scene with each effect's data-dependent choices made
        (`AbstractEffect.resolved`) at the initial time, states and parameters."""
        effects = tuple(e.resolved(t0, jnp.asarray(x0), args) for e in self.effects)
        if all(new is old for new, old in zip(effects, self.effects)):
            return self
        return dataclasses.replace(self, effects=effects)


def _first_member(args, axes):
    # The first member of a batch of parameters (leaves batched along `axes` = 0), for
    # decisions made from the parameters' structure; other axes: the parameters as given.
    if axes != 0:
        return args
    return jax.tree.map(lambda a: a[0] if np.ndim(a) > 0 else a, args)
