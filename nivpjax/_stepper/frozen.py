r"""The frozen smooth system of an event-driven step: the face of every set-valued law
held fixed between two events.

Between events a nonsmooth model is smooth. On its algebraic rows $z$ the projected
equation is $z = P(z + \rho f_z(t, y))$; on a fixed face of a box (the interval of a
relay, a saturation, a diode's half-line) $P$ is affine, and the rows split in two:

- **at a bound** (the multiplier sits on a face of its set: a relay in crossing mode,
  $w = \pm 1$; a saturated signal): $z$ is that bound, constant;
- **interior** (the multiplier lies strictly inside its set): the law leaves it free and
  the projected equation reduces to $f_z(t, y) = 0$. On an *equation row* (index 1: a
  saturation's $\sigma = u(t, x)$) that determines $z$ directly; on a *selection row*
  (index 2: a relay in sliding mode, $0 = s(t, x)$ with no $w$ in it) its derivative along
  the flow does, $\partial_t s + \partial_x s\,\dot x(t, x, w) = 0$: Utkin's equivalent
  control, which keeps the state on the surface.

The face is left at an *event*: a held row's switching function $\pm f_z$ changes sign
(the flow crosses the surface) or an interior row's value reaches a bound of its set (a
sliding relay's equivalent control reaching $\pm 1$, the multiplier-side event).
`switching` returns those functions, positive while the face holds.

Restriction: separable laws, whose projector's Jacobian on the algebraic rows is diagonal
(boxes, signs, saturations, diodes written on multipliers). Laws on differential rows
(friction as a proximal map, contacts) are not frozen here; the stepper refuses them.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .. import _linalg
from .._model import Model
from .._projector import ProjectionContext


# The look-ahead that decides a face, as a fraction of the step: the flow from the step's
# start over this time tells, at a state on a switching surface, which side it goes to.
LOOK_AHEAD = 1e-3
# Newton iterations on the algebraic rows of the frozen system (exact in one for a law
# affine in its multipliers; the second confirms it to round-off).
NEWTON_ITERATIONS = 2
# A far point in the directions of the algebraic rows, to read the bounds of their sets
# off the projector (relative to 1 + |z|).
FAR = 1e8


class Face(eqx.Module):
    """The face of every algebraic row, frozen for one step.

    - `interior`: rows whose multiplier lies inside its set (determined by its equation,
      or by the hidden constraint on selection rows).
    - `bound`: the value of the other algebraic rows (a bound of their set).
    - `lower`, `upper`: the bounds of each algebraic row's set (read at the face's
      decision; large where a set is unbounded).
    - `side`: +1 where a row sits at its upper bound, -1 at its lower one.
    """

    interior: Bool[Array, " n"]
    bound: Float[Array, " n"]
    lower: Float[Array, " n"]
    upper: Float[Array, " n"]
    side: Float[Array, " n"]


def _rho(model: Model, h, dtype):
    # The scaling of the algebraic rows in a stage of length h (see `Model.solve_stage`).
    alg_rho = model.tau / h
    if model.equation_rows is not None:
        alg_rho = jnp.where(model.equation_rows, model.tau, alg_rho)
    return jnp.broadcast_to(jnp.asarray(alg_rho, dtype), model.algebraic.shape)


def _project(model: Model, t, h, y, v, rho, args):
    ctx = ProjectionContext(t=t, h=h, y_prev=y, y_iter=y, rho=rho, args=args)
    return model.projector(v, ctx)


def decide_face(model: Model, t0, h, y0, args) -> Face:
    r"""The face of every algebraic row for a step from `(t0, y0)` of length `h`: the
    projector's Jacobian at $v = z_0 + \rho f_z(t_0 + \delta, y_0 + \delta \dot y_0)$,
    $\delta$ = `LOOK_AHEAD` $h$ (the state a little along the flow, so that a state on a
    switching surface takes the face of the side the flow goes to) and $\rho$ the
    scaling of a stage of length $\delta$, its diagonal read as 1 (interior) or 0 (at a
    bound). The algebraic rows of `y0` carry the previous
    face: the values the last step ended with, or the selection an event's projected
    problem decided. No gradient: a face is a discrete choice."""
    sg = jax.lax.stop_gradient
    y0 = sg(y0)
    alg = model.algebraic
    dtype = y0.dtype
    delta = LOOK_AHEAD * h
    rate = model.to_state(model.f(t0, y0, args))
    ahead = y0 + delta * rate
    # Selection rows scaled as a stage of length delta: their residual (a switching
    # function) over delta is its rate along the flow plus its value over delta, so
    # a state on the surface decides by the rate and one off it by its side, whatever h.
    rho = _rho(model, delta, dtype)
    v = jnp.where(alg, y0 + rho * model.f(t0 + delta, ahead, args), y0)
    t_end = t0 + h
    project = lambda u: _project(model, t_end, h, y0, u, rho, args)  # noqa: E731
    value = project(v)
    slope = jnp.diagonal(jax.jacfwd(project)(v))
    far = FAR * (1 + jnp.abs(y0))
    lower = project(jnp.where(alg, y0 - far, y0))
    upper = project(jnp.where(alg, y0 + far, y0))
    # A row exactly at a bound (where an event's decision or the last step left it)
    # stays there unless the flow points clearly inside: at a sliding mode's tangential
    # exit the rate is zero to round-off and a state 1e-17 on the wrong side would read
    # as sliding again.
    tol = jnp.sqrt(jnp.finfo(dtype).eps) * (1 + jnp.abs(y0))
    at_lower, at_upper = alg & (y0 == lower), alg & (y0 == upper)
    inward = jnp.where(at_upper, upper - v, v - lower)
    stay = (at_lower | at_upper) & (inward <= tol)
    interior = alg & (slope > 0.5) & ~stay
    value = jnp.where(stay, y0, value)
    side = jnp.where(jnp.abs(value - upper) <= jnp.abs(value - lower), 1.0, -1.0)
    return sg(Face(interior, value, lower, upper, side.astype(dtype)))


def _conditions(model: Model, face: Face, t, y, args):
    # The frozen system's equations on the algebraic rows (zero elsewhere): the bound on
    # rows at a bound, f_z on interior equation rows, its derivative along the flow on
    # interior selection rows.
    alg = model.algebraic
    f = model.f(t, y, args)
    at_bound = y - face.bound
    if not model.has_selections:
        return jnp.where(alg, jnp.where(face.interior, f, at_bound), 0.0)
    rate = model.to_state(f)
    along = jax.jvp(lambda tt, yy: model.f(tt, yy, args), (t, y), (jnp.ones_like(t), rate))[1]
    sel = jnp.asarray(model.selection_rows)
    free = jnp.where(sel, along, f)
    return jnp.where(alg, jnp.where(face.interior, free, at_bound), 0.0)


class Frozen(eqx.Module):
    """The frozen system of one step: its `face`, and `inverse`, the inverse of the
    Jacobian of its algebraic conditions with respect to the algebraic rows at the step's
    start (identity on differential rows), with which every solve of the step iterates
    (a chord Newton: exact in one iteration for a law affine in its multipliers)."""

    face: Face
    inverse: Float[Array, "n n"]


def freeze(model: Model, t0, h, y0, args) -> Frozen:
    """The frozen system for a step from `(t0, y0)` of length `h` (see `decide_face`)."""
    return on_face(model, decide_face(model, t0, h, y0, args), t0, y0, args)


def on_face(model: Model, face: Face, t0, y0, args) -> Frozen:
    """The frozen system of a given `face`, its chord inverse taken at `(t0, y0)`."""
    n = y0.shape[0]
    eye = jnp.eye(n, dtype=y0.dtype)
    if not model.has_algebraic:
        return Frozen(face, eye)
    alg = model.algebraic
    y0 = jax.lax.stop_gradient(y0)
    J = jax.jacfwd(lambda yy: _conditions(model, face, t0, yy, args))(y0)
    M = jnp.where(alg[:, None] & alg[None, :], J, eye)
    columns = jax.vmap(_linalg.solve_or_nan, in_axes=(None, 1), out_axes=1)
    return Frozen(face, jax.lax.stop_gradient(columns(M, eye)))


def candidates(face: Face, row):
    r"""The three faces that differ from `face` at most in `row`: `row` interior, at its
    lower bound, at its upper bound (stacked, a leading axis of 3)."""
    faces = []
    for interior, at_upper in ((True, True), (False, False), (False, True)):
        bound = jnp.where(at_upper, face.upper[row], face.lower[row])
        side = jnp.where(at_upper, 1.0, -1.0).astype(face.side.dtype)
        faces.append(
            Face(
                face.interior.at[row].set(interior),
                face.bound.at[row].set(bound),
                face.lower,
                face.upper,
                face.side.at[row].set(side),
            )
        )
    return jax.tree.map(lambda *x: jnp.stack(x), *faces)


def holds(model: Model, frozen: Frozen, t, y, args, tol):
    r"""Whether the frozen face holds just after `(t, y)`: every switching function $g$
    along the frozen flow is positive there, or within `tol` of zero and rising, or zero
    with zero rate and convex (its second derivative positive: the tangential departure
    of a sliding mode's exit, where the flow leaves the surface quadratically). The flow is
    its second-order Taylor polynomial, $y + \tau \dot y + \tfrac{\tau^2}{2} \ddot y$, so
    that the derivatives of $g$ at $\tau = 0$ are exact to second order (JVPs through the
    algebraic solve)."""

    def rate(tau, u):
        return frozen_rate(model, frozen, t + tau, u, args)[0]

    zero = jnp.zeros((), y.dtype)
    one = jnp.ones_like(zero)
    r0 = rate(zero, y)
    r1 = jax.jvp(lambda tau: rate(tau, y + tau * r0), (zero,), (one,))[1]

    def g(tau):
        u = y + tau * r0 + 0.5 * tau**2 * r1
        u = algebraic_values(model, frozen, t + tau, u, args)
        return switching(model, frozen, t + tau, u, args)

    def g_and_rate(tau):
        return jax.jvp(g, (tau,), (one,))

    (value, first), (_, second) = jax.jvp(g_and_rate, (zero,), (one,))
    rises = (first > tol) | ((first >= -tol) & (second > 0))
    return jnp.all((value > tol) | ((value >= -tol) & rises))


def algebraic_values(model: Model, frozen: Frozen, t, y, args):
    r"""`y` with its algebraic rows solved from the frozen system at `(t, y)` (differential
    rows unchanged): `NEWTON_ITERATIONS` chord iterations on `_conditions` with the step's
    `Frozen.inverse`, from the rows' values in `y`. Differentiable (the iterations are
    traced: for an affine law the derivative is the implicit function theorem's)."""
    if not model.has_algebraic:
        return y
    alg = model.algebraic
    for _ in range(NEWTON_ITERATIONS):
        g = _conditions(model, frozen.face, t, y, args)
        y = y - jnp.where(alg, frozen.inverse @ g, 0.0)
    return y


def frozen_rate(model: Model, frozen: Frozen, t, y, args):
    """`(rate, y_full)`: the frozen system's rate of the differential rows at `(t, y)`
    (zero on algebraic rows) and `y` with its algebraic rows solved."""
    y_full = algebraic_values(model, frozen, t, y, args)
    return model.to_state(model.f(t, y_full, args)), y_full


def switching(model: Model, frozen: Frozen, t, y_full, args):
    r"""The switching functions of the frozen face at a solved state `y_full`, per row,
    positive while the face holds (`inf` on differential rows): $\pm f_z$ on rows at a
    bound (the side's sign: a relay at $w = 1$ holds while $s > 0$), the distance to the
    nearer bound on interior rows (a sliding relay's $1 - |w|$)."""
    alg = model.algebraic
    face = frozen.face
    f = model.f(t, y_full, args)
    crossing = face.side * f
    inside = jnp.minimum(y_full - face.lower, face.upper - y_full)
    g = jnp.where(face.interior, inside, crossing)
    return jnp.where(alg, g, jnp.inf)
