"""The projector interface and the context a projector is evaluated in."""

import abc
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PyTree


class ProjectionContext(eqx.Module):
    """Everything a state-dependent set may depend on during one implicit stage.

    **Fields:**

    - `t`: the time at the end of the stage, where the implicit equation is collocated.
    - `h`: the stage's step size.
    - `y_prev`: the state at the start of the stage (pre-impact velocities are read here).
    - `y_iter`: the current nonlinear iterate. State-dependent bounds (e.g. a friction bound
        $\\mu N(y)$) are evaluated here, so autodiff supplies their chain rule in the
        generalised Jacobian.
    - `rho`: the per-component scaling $\rho$ of the stage's map $y - \rho R(y)$ (for the
        components the projector acts on). Proximal maps (Coulomb friction without a
        multiplier state) and resolvents need it; true projections ignore it.
    - `args`: the user's parameters.
    - `block`: inside a [`nivpjax.BlockProjector`][], the indices of the block being
      projected (`None` outside one); `restrict` maps a full-state vector to the block.
    - `rate`: the vector field $f(t, y_{\text{iter}})$ at the end of a step, full state;
      set only when a step's `violation` is checked (`None` inside a stage).
    """

    t: Float[Array, ""]
    h: Float[Array, ""]
    y_prev: Float[Array, " n"]
    y_iter: Float[Array, " n"]
    rho: Float[Array, " m"]
    args: PyTree[Any]
    block: tuple[int, ...] | None = eqx.field(static=True, default=None)
    rate: Float[Array, " n"] | None = None

    def restrict(self, v):
        """The components of a full-state vector `v` that belong to this block."""
        return v if self.block is None else v[jnp.asarray(self.block)]


def default_context(z: Array, args: PyTree[Any] = None) -> ProjectionContext:
    """A context for evaluating a projector outside a time step (tests, interactive use):
    `t = 0`, `h = 1`, `rho = 1`, and both states equal to `z`."""
    z = jnp.asarray(z)
    zero = jnp.zeros((), z.dtype)
    one = jnp.ones((), z.dtype)
    return ProjectionContext(t=zero, h=one, y_prev=z, y_iter=z, rho=jnp.ones_like(z), args=args)


class AbstractProjector(eqx.Module):
    """A Euclidean (or metric) projection onto a closed convex set $K$, possibly depending on
    the context.

    Subclasses implement `__call__(z, ctx) -> P_K(z)`. The map must be differentiable in the
    sense of `jax.jvp` everywhere: kinks carry a `jax.custom_jvp` rule choosing one element of
    the generalised (Clarke/B-) Jacobian, documented in the subclass.

    Convention for kinks, shared by every built-in projector: a point on the boundary between
    two smooth pieces takes the Jacobian of the piece whose closed region, listed in the
    order *interior of $K$*, *polar/normal region*, *boundary pieces*, contains it first. In
    particular a point of $K$ always gets the identity: it is the one-sided derivative from
    inside the set, keeps the Newton matrix $I - D(I - \\rho J_R)$ equal to $\\rho J_R$ on free
    components, and makes implicit gradients at grazing contact equal to those of the
    unconstrained flow.
    """

    @abc.abstractmethod
    def __call__(self, z: Float[Array, " n"], ctx: ProjectionContext) -> Float[Array, " n"]:
        """Project `z` onto the set described by this projector in context `ctx`."""

    def validate(self, n: int) -> None:
        """Check, before any work, that this projector fits a state of size `n` (indices in
        range). Raises `ValueError`. Default: nothing to check."""

    def violation(self, ctx: ProjectionContext) -> Float[Array, ""]:
        """How far the state at the end of a step, `ctx.y_iter`, violates a constraint that
        was not enforced during the step because it was inactive at its start `ctx.y_prev`
        (e.g. the penetration of a contact crossed inside the step). Controllers treat it as
        a local error, which locates such events. Default: 0 (sets enforced throughout)."""
        return jnp.zeros((), ctx.y_iter.dtype)

    def initial_violation(self, ctx: ProjectionContext) -> Float[Array, ""]:
        """How far the initial state `ctx.y_prev` violates a constraint that no stage can
        restore (e.g. a contact that starts penetrated: velocity-level contact keeps the
        penetration). The solve reports `initial_state_infeasible` when it exceeds
        round-off. Default: 0 (constraints enforced by the first stage)."""
        return jnp.zeros((), ctx.y_prev.dtype)

    @property
    def has_event_time(self) -> bool:
        """Whether `event_time` can report an event (static: a model without one skips the
        event-sensitivity work of each stage)."""
        return False

    def event_time(self, ctx: ProjectionContext) -> tuple[Float[Array, ""], Bool[Array, ""]]:
        """`(tau, found)` for a stage starting at `ctx.y_prev`: whether the stage applies an
        event (an impact) at a fixed point of the stage although the flow reaches it
        `tau` later than the stage start, `tau` differentiable in `ctx.y_prev` and
        `ctx.args`. The stage uses it only for derivatives (the saltation term: how the
        event time moves with the state and parameters); values are unaffected. Default:
        no event."""
        return jnp.zeros((), ctx.y_prev.dtype), jnp.zeros((), bool)

    def impulsive(self, ctx: ProjectionContext) -> Bool[Array, ""]:
        """Whether the stage from `ctx.y_prev` to `ctx.y_iter` contained an impulse (a jump
        of the state, e.g. an impact). Multistep stages (Bathe's backward difference) must
        not extrapolate across it. Default: False (bounded reactions only)."""
        return jnp.zeros((), bool)


Bound = Float[Array, "..."] | Callable[[Any, Any, Any], Any]


def resolve(value, ctx: ProjectionContext, dtype) -> Array:
    """Evaluate a bound that is either an array or a callable `bound(t, y, args)` of the
    current iterate."""
    if callable(value):
        value = value(ctx.t, ctx.y_iter, ctx.args)
    return jnp.asarray(value, dtype=dtype)
