"""The stepper interface."""

import abc
import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._model import Model
from .._nonlinear import AbstractNonlinearSolver, SemismoothNewton
from .._solution import StepStats


class StepOutput(eqx.Module):
    """One attempted step: the candidate `y1`, its local error estimate `y_error` (`None` when
    the scheme has none), the stage residual at `y1` (`multipliers`), and `stats`.

    `h_taken`: where a stepper ends the step short of its size, at an event it located
    (`AbstractStepper.locates_events`), the length it covered; `y1` is the state there.
    `None`: the whole step."""

    y1: Float[Array, " n"]
    y_error: Float[Array, " n"] | None
    multipliers: Float[Array, " n"]
    stats: StepStats
    h_taken: Float[Array, ""] | None = None


class AbstractStepper(eqx.Module):
    """An implicit one-step scheme whose stages are variational inequalities solved by
    `solver`.

    Subclasses implement `step(model, t0, h, y0, args) -> StepOutput` and declare `order`
    (of the propagated solution) and `error_order` (the power of $h$ in the local error
    estimate, used by controllers; 0 when there is no embedded estimate).
    """

    solver: eqx.AbstractVar[AbstractNonlinearSolver]

    @property
    @abc.abstractmethod
    def order(self) -> int: ...

    @property
    def error_order(self) -> int:
        return 0

    def with_solver(self, solver: AbstractNonlinearSolver) -> "AbstractStepper":
        """This stepper with its stages solved by `solver` (the loop passes its own solver
        held to the error control's tolerances, see
        [`nivpjax.AbstractNonlinearSolver`][])."""
        return eqx.tree_at(lambda s: s.solver, self, solver)

    @property
    def locates_events(self) -> bool:
        """Whether the stepper locates the model's events itself and ends its steps there
        (`StepOutput.h_taken`): the loop then asks the model for no violation, event
        prediction or held exit."""
        return False

    def dense_output(self, model: Model, t, t0, y0, t1, y1, args):
        """`(value, usable)`: the state at `t` inside the accepted step from `(t0, y0)` to
        `(t1, y1)` by the stepper's own continuous extension, and whether it vouches for
        this step; `None` (the default): the loop's interpolant (`nivpjax._loop.interpolate`)."""
        return None

    def validate_model(self, model: Model) -> None:
        """Check, before any work, that this stepper handles `model` (its arrays are
        concrete here). Raises `ValueError`. Default: every model."""

    @abc.abstractmethod
    def step(self, model: Model, t0, h, y0, args) -> StepOutput: ...


def default_solver() -> AbstractNonlinearSolver:
    return SemismoothNewton()


def stats_of(sol) -> StepStats:
    return StepStats(
        iterations=sol.iterations, residual_norm=sol.residual_norm, nonlinear_result=sol.result
    )


class Stage(eqx.Module):
    """The inputs of one stage of `Model.solve_stage`: its end time, its length, its base
    point, its implicit weight, its start point, and the solve's initial guess (the start point
    if `None`)."""

    t_end: Array
    h_eff: Array
    y_base: Array
    theta: Array
    y_prev: Array
    guess: Array

    @classmethod
    def of(cls, t_end, h_eff, y_base, theta, y_prev, guess=None):
        dtype = y_prev.dtype
        as_float = lambda x: jnp.asarray(x, dtype)  # noqa: E731
        guess = y_prev if guess is None else guess
        return cls(as_float(t_end), as_float(h_eff), y_base, as_float(theta), y_prev, guess)


def chained_stages(
    model: Model,
    solver: AbstractNonlinearSolver,
    f_explicit,
    first: Stage,
    follow: Callable,
    count: int,
    args,
):
    """Solve `count` stages, each from what the previous one gives, as one traced stage
    (a `lax.scan`): the Newton iteration, its line search and the projector's Jacobian are
    compiled once for all the stages of a step, not once per stage (a Bathe step on the
    ball compiles in a quarter less time this way, at the same cost per step).

    Every stage reads the explicit rate `f_explicit` with weight `1 - theta` (a stage with
    `theta = 1` ignores it). `follow(stage, sol, multipliers)` returns the next stage's
    inputs and per-stage outputs (a pytree of arrays); it also runs after the last stage,
    whose next inputs are dropped.

    Returns, per stage (a list), `(value, stats, multipliers, outputs)`."""

    def body(stage, _):
        sol, multipliers = model.solve_stage(
            solver,
            stage.t_end,
            stage.h_eff,
            stage.y_base,
            f_explicit,
            stage.theta,
            stage.y_prev,
            stage.guess,
            args,
        )
        following, out = follow(stage, sol, multipliers)
        return following, _pack((sol.value, stats_of(sol), multipliers, out), first.y_prev.dtype)

    structure = []
    _, packed = jax.lax.scan(lambda c, x: _recorded(body, structure, c, x), first, length=count)
    return [_unpack(jax.tree.map(lambda x: x[k], packed), structure[0]) for k in range(count)]


def _recorded(body, structure, carry, x):
    following, (packed, tree) = body(carry, x)
    structure.append(tree)
    return following, packed


def _pack(tree, dtype):
    # The stage outputs as one float vector and one int vector: a scan stacks each output
    # leaf with its own update per iteration, and those are kernel launches on CPU.
    leaves, treedef = jax.tree.flatten(tree)
    floats = [jnp.ravel(x) for x in leaves if _is_float(x.dtype)]
    ints = [jnp.ravel(x).astype(jnp.int32) for x in leaves if not _is_float(x.dtype)]
    layout = (treedef, [(x.shape, x.dtype) for x in leaves])
    packed = (
        jnp.concatenate(floats).astype(dtype) if floats else jnp.zeros((0,), dtype),
        jnp.concatenate(ints) if ints else jnp.zeros((0,), jnp.int32),
    )
    return packed, layout


def _unpack(packed, layout):
    treedef, specs = layout
    offsets = {True: 0, False: 0}
    leaves = []
    for shape, dtype in specs:
        is_float = _is_float(dtype)
        vector = packed[0] if is_float else packed[1]
        size = math.prod(shape)
        start = offsets[is_float]
        offsets[is_float] = start + size
        leaves.append(vector[start : start + size].reshape(shape).astype(dtype))
    return jax.tree.unflatten(treedef, leaves)


def _is_float(dtype):
    return jnp.issubdtype(dtype, jnp.inexact)
