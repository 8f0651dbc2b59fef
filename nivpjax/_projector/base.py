"""The projector interface and the context a projector is evaluated in."""

import abc
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import lax
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
    - `rho`: the per-component scaling $\\rho$ of the stage's map $y - \\rho R(y)$ (for the
        components the projector acts on). Proximal maps (Coulomb friction without a
        multiplier state) and resolvents need it; true projections ignore it.
    - `args`: the user's parameters.
    - `block`: inside a [`nivpjax.BlockProjector`][], the indices of the block being
      projected (`None` outside one); `restrict` maps a full-state vector to the block.
    - `rate`: the vector field $f(t, y_{\\text{iter}})$ at the end of a step, full state;
      set only when a step's `violation` is checked (`None` inside a stage). For
      `switch_shift`, the rate of the differential rows at the stage start instead.
    - `rate_at`: for `switch_shift` only, the rate of the differential rows at the stage
      start as a function of the full state (to evaluate it on another branch of a
      switch: other multiplier values); `None` otherwise.
    - `start_rate`: the rate of the differential rows at the stage start, $f(t - h,
      y_{\\text{prev}})$ in state units, for projectors that predict events from the start
      (a contact's normal acceleration tells a graze from an impact); set by the model for
      projectors with events (`has_event_time`), `None` otherwise.
    - `end_rate`: the rate $y'$ of the differential rows at the end of a step (state
      units, zero on algebraic rows), set with `rate` when the model asks for
      `next_event`; `None` otherwise.
    - `y_next`, `next_rate`: the state the next step starts from at the end of this
      one, and its rate (differential rows, state units): the right-limit selections of
      `start_selection` (a step that ends just short of a relay's switch continues on its
      far branch) and the switch moved to the start. Set with `end_rate` for projectors
      with start selections; `None` otherwise.
    - `after_end`: `True` when a controller asks `next_event` for the first event after
      the step's end (to size the next step): an event at the end itself, which the next
      step starts on, is then left out, so that it does not hide the one after it, and
      so is one the state reaches within a fraction of the controller's `tolerance`.
      `False` when a stepper asks for the events inside its step.
    - `tangent`: `True` when the projector is evaluated to linearise a stage at its
      solution (the element of the generalised Jacobian that derivatives use, through the
      implicit function theorem), `False` during the nonlinear iteration. Projectors that
      pick the derivative's element by where the stage switched read it; values must not
      depend on it.
    - `law`: `True` when the projector is evaluated for the reaction its law applies at a
      point (`Model.law_reaction`: the one-sided derivative of $P_s(y + s f)$ at
      $s \to 0^+$, which a stage of the theta family weighs at both ends). A projector
      with impulses then keeps only its persistent contacts: an impact at that point
      is no smooth reaction (its holding part would be read as a force that the
      impact's flight never has).
    - `tolerance`: `(rtol, atol)` of the controller that judges a step's `violation`
      or sizes the next step by `next_event` (`None` elsewhere, and under a controller
      without tolerances). The violation is
      charged against `nivpjax._norms.violation_scale`, the start
      state's scale; a projector whose violation has a scale of its own converts it with
      these (a contact's penetration is judged like an error in its gap).
    - `violation_scale`: that scale, as the controller computes it (over the rows its
      error norm judges); `None` where `tolerance` is.
    """

    t: Float[Array, ""]
    h: Float[Array, ""]
    y_prev: Float[Array, " n"]
    y_iter: Float[Array, " n"]
    rho: Float[Array, " m"]
    args: PyTree[Any]
    block: tuple[int, ...] | None = eqx.field(static=True, default=None)
    rate: Float[Array, " n"] | None = None
    rate_at: Callable[[Array], Array] | None = None
    start_rate: Float[Array, " n"] | None = None
    end_rate: Float[Array, " n"] | None = None
    y_next: Float[Array, " n"] | None = None
    next_rate: Float[Array, " n"] | None = None
    after_end: bool = eqx.field(static=True, default=False)
    tangent: bool = eqx.field(static=True, default=False)
    law: bool = eqx.field(static=True, default=False)
    tolerance: tuple[Any, Any] | None = None
    violation_scale: Any = None

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

    def next_event(self, ctx: ProjectionContext) -> Float[Array, ""]:
        """The predicted time, from the start of the attempt `ctx.t - ctx.h`, of the first
        event (a contact closing, a switching function crossing zero) after the attempt's
        start, estimated from the data at its two ends `ctx.y_prev` and `ctx.y_iter`
        (`ctx.rate` holds the vector field at the end). It may lie inside the attempt (the
        event was crossed) or beyond it (the event is coming). Controllers use it to
        propose a step that lands just past the event; rejection stays the safety net.
        Default: `inf` (nothing predicted)."""
        return jnp.full((), jnp.inf, ctx.y_iter.dtype)

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

    def impact(self, ctx: ProjectionContext) -> Float[Array, " n"]:
        """The state (restricted to the projector's components) right after the impulses
        the projector applies at the start of a step, from `ctx.y_prev`: Newton's impact
        law for contacts that are closed (or closing within the step) and approaching.
        Steppers apply it before their stages, so that the stages integrate the smooth
        flow after the impact (Moreau's impact-then-flow). Default: no impulse."""
        return ctx.restrict(ctx.y_prev)

    def switched(self, ctx: ProjectionContext) -> Bool[Array, ""]:
        """Whether the stage from `ctx.y_prev` to `ctx.y_iter` changed the face of the set
        that the state lies on (a multiplier leaving a bound or reaching one, friction
        sticking or slipping, a contact opening or closing): the rate may then jump inside
        the stage, so multistep stages (Bathe's backward difference) must not extrapolate
        across it. Default: False (a single smooth piece)."""
        return jnp.zeros((), bool)

    @property
    def has_switch_shift(self) -> bool:
        """Whether `switch_shift` can report a switch (static: a model without one skips
        the switch-sensitivity work of each stage)."""
        return False

    def switch_shift(
        self, ctx: ProjectionContext
    ) -> tuple[Float[Array, " m"], Float[Array, " m"], Bool[Array, ""]]:
        r"""The event-time (saltation) sensitivity of a stage that switches branch:
        `(base_shift, end_shift, found)`, two vectors over the projector's components that
        are zero in value, and whether the stage switched.

        Called with `ctx.y_prev` the stage start, `ctx.y_iter` the stage solution (its
        branch is read there) and `ctx.rate` the rate of the differential rows at the stage
        start ($A^{-1} f$ there, zero on algebraic rows). With the switch at
        $\tau = -s_0/\dot s^-$ after the stage start ($s$ the switching function),
        `base_shift` has derivative $(f^- - f^+)\,d\tau$: the stage adds it to its base
        point, so the saltation term propagates through the stage's own sensitivity.
        `end_shift` is added to the stage's solution instead, for a stage whose result does
        not depend on its start (a velocity stuck by friction on its way to reversing).
        On differential components the entries are state displacements (a jump of the
        friction force times $\delta\tau$); on algebraic components of `base_shift`,
        multiplier displacements (a relay selection jump times $\delta\tau$) that the
        model maps through the vector field. Default: no switch (or a vector field
        continuous across it: no first-order term is missing)."""
        zero = jnp.zeros_like(ctx.rho)
        return zero, zero, jnp.zeros((), bool)

    @property
    def has_arrests(self) -> bool:
        """Whether `arrest_error` can report a row (static: a model without one skips that
        work in each step)."""
        return False

    def arrest_error(self, ctx: ProjectionContext) -> tuple[Bool[Array, " m"], Float[Array, " m"]]:
        r"""`(arrested, error)` over the projector's components for a step from
        `ctx.y_prev` to `ctx.y_iter` (`ctx.start_rate`, `ctx.end_rate`: the rates at its
        ends, state units): the rows that came to rest inside the step (a sliding velocity
        stuck by friction at the end), and the local error of their value at the end.

        A row at rest at the end has the exact value there when the flow it left reached
        rest inside the step and the law holds it (the end's reaction inside its bound,
        which `violation` checks): the timing of the arrest is an error of the rows that
        integrate it (a position), whose estimates stay. A smooth-rate estimate on the row
        itself (a divided difference of rates that jump at the arrest, or the change of an
        applied force that the reaction cancels) measures the jump instead, at any step
        size, and collapses the step at each arrest. `error`: the value the row would still
        have at the end along the flow it left, where that flow had not reached rest by
        then (the row stopped early); zero where it had. Default: none."""
        m = ctx.rho.shape
        return jnp.zeros(m, bool), jnp.zeros(m, ctx.y_iter.dtype)

    @property
    def has_start_selection(self) -> bool:
        """Whether `start_selection` can change a selection (static: a model without one
        skips that work at the start of each step)."""
        return False

    def start_selection(
        self, ctx: ProjectionContext
    ) -> tuple[Float[Array, " m"], Float[Array, ""]]:
        r"""The right-limit selection at the start of a step, from `ctx.y_prev` (restricted
        to the projector's components), with `ctx.t - ctx.h` the step's start and
        `ctx.rate_at` the rate of the differential rows there as a function of the full
        state. A step that lands on a switching surface ends with the multiplier that made
        it land (an average over that step), not the selection the flow takes from there
        (a sliding mode's equivalent control); a scheme that reads the rate at the start
        of the next step (the trapezoidal rule, Bathe's first stage, an embedded
        estimate) would apply that average once more. A projector may also move a switch
        that the step reaches very early to its start. Returns `(selection, skipped)`:
        `skipped` the time from the step's start to the switch so moved (0 if none; the
        model shifts the start's differential rows by `skipped` times the jump of the
        rate, to the state the far branch carries to the exact one at the switch).
        Default: `ctx.y_prev` unchanged, 0."""
        return ctx.restrict(ctx.y_prev), jnp.zeros((), ctx.y_prev.dtype)

    def acts_on(self, n: int) -> np.ndarray:
        """The rows of a state of size `n` that the projector may move (a static NumPy
        mask; rows it never moves carry no reaction, so their rate is the vector field's).
        Default: all."""
        return np.ones(n, bool)

    def weighed_rows(self, n: int) -> np.ndarray:
        r"""The rows of a state of size `n` whose reaction is a bounded force that varies
        smoothly along a phase (a static NumPy mask): Coulomb friction as a proximal map.
        A stage of the theta family weighs it like the vector field, at both ends (see
        `Model.solve_stage`), instead of applying it whole at the stage's end. Default:
        none (normal cones: impulses and holding forces stay at the stage's end)."""
        return np.zeros(n, bool)

    @property
    def has_kinks(self) -> bool:
        """Whether `early_kinks` can report a crossing (static: a model without kinks
        skips that work in each stage)."""
        return False

    def early_kinks(self, ctx: ProjectionContext) -> Bool[Array, " m"]:
        r"""Which components (restricted to the projector's) switched branch at a kink of
        the vector field (continuous multipliers, e.g. a diode turning off) in the first
        half of the stage from `ctx.y_prev` to `ctx.y_iter`. A stage's explicit start rate
        (the trapezoidal rule's $f_0$) then takes their multipliers' derivatives from the
        stage's end: the branch the flow follows from just after the start. Default:
        none."""
        return jnp.zeros(ctx.restrict(ctx.y_prev).shape, bool)

    def impulsive(self, ctx: ProjectionContext) -> Bool[Array, ""]:
        """Whether the stage from `ctx.y_prev` to `ctx.y_iter` contained an impulse (a jump
        of the state, e.g. an impact). Multistep stages (Bathe's backward difference) must
        not extrapolate across it. Default: False (bounded reactions only)."""
        return jnp.zeros((), bool)


Bound = Float[Array, "..."] | Callable[[Any, Any, Any], Any]


def face(z, lower, upper):
    """The face of the interval $[\\ell, u]$ that `z` lies on: -1 at the lower bound (or
    below), +1 at the upper bound (or above), 0 inside."""
    return jnp.where(z <= lower, -1, jnp.where(z >= upper, 1, 0))


def resolve(value, ctx: ProjectionContext, dtype) -> Array:
    """Evaluate a bound that is either an array or a callable `bound(t, y, args)` of the
    current iterate."""
    if callable(value):
        value = value(ctx.t, ctx.y_iter, ctx.args)
    return jnp.asarray(value, dtype=dtype)


def switch_delay(s0, sdot, found):
    r"""$\delta = \tau - \text{stop\_gradient}(\tau)$ with $\tau = -s_0/\dot s^-$, the first-order
    time from the stage start to the zero of a switching function $s$ ($s_0$ its value at
    the start, $\dot s^-$ its rate on the pre-switch branch): zero in value, derivative
    $d\tau$. Zero where nothing switched or $\dot s^- = 0$ (a grazing switch has no
    first-order time)."""
    ok = found & (sdot != 0)
    tau = -s0 / jnp.where(ok, sdot, 1.0)
    return jnp.where(ok, tau - lax.stop_gradient(tau), 0.0)
