r"""Held phases: a multiplier kept inside its set by an algebraic constraint (a relay in
sliding mode, a block stuck by cone friction), and the exits from them that a step's two
ends do not show.

A selection row $w$ (an algebraic row that is not an equation row) is *held* at a state
when its projected equation is locally a translation in $w$ (the multiplier lies in the
interior of its set): its row of $y - P(y - \rho R)$ is then a function
$\sigma(t, x)$ of the time and the differential states alone, which the phase keeps at
zero. Differentiating along the flow gives the hidden constraint

$$ G(w) = \partial_t \sigma + \partial_x \sigma \cdot \dot x(t, x, w) = 0, $$

whose solution is Filippov's equivalent control (a relay's $w = u(t)$ on $x' = -w + u$).
The phase ends where it leaves the set. A step whose two ends are both held says nothing
about what happened between them: backward Euler stepped over two whole excursions of a
forced relay from sliding ($x' = -w + 1.3\sin 2t$, $w \in \operatorname{sign} x$: one step
from $t = 4.37$ to $8$) and converged, as rtol fell, to a solution that slides forever.
`held_exit` samples the equivalent control inside such a step."""

import jax
import jax.numpy as jnp

from . import _linalg
from ._hermite import cubic_hermite
from ._projector import ProjectionContext


# Interior sample points c = k / (SAMPLES + 1), k = 1..SAMPLES, of a step held at both ends.
# The sampled excursion of the equivalent control must span more than 1/(SAMPLES + 1) of
# the step to be seen; the steps that straddle one are long (error estimates see nothing
# while the phase holds), and the excursions they hide are a sizeable part of them.
SAMPLES = 8
# A held row's hidden constraint determines its multiplier where G's dependence on the
# multipliers is at least this fraction of |d sigma/dx| |dx'/dw| (see `_linearisation`).
DETERMINED = 1e-3
# The selection rows' scaling in the equivalent control of an output time, relative to
# a stage's (see `selections_inside`).
EQUIVALENT_SCALE = 1e-6


def held_exit(model, t1, h, y0, y1, rate0, rate1, args):
    r"""`(violation, time)` for the step from `(t1 - h, y0)` to `(t1, y1)` of `model`:

    - `violation`: where every selection row that moves is held at both ends, the
      largest drift $h\,\|\dot x(w) - \dot x(P w)\|_\infty$ (state units) at the
      interior sample points where the equivalent control $w$ lies outside its set
      ($P w$ its projection): how far the state leaves the constraint over the step once
      the phase has ended; 0 otherwise.
    - `time`: from the step's start, the last sample point before the first one outside
      the set (the controller retries up to there), `inf` if none.

    Differential states at the samples come from the cubic Hermite interpolant of the
    ends and their rates `rate0`, `rate1` (state units); multipliers from the linear one,
    improved by one Newton step on $G(w) = 0$ (exact for $\dot x$ affine in $w$). No
    gradient: it only decides steps."""
    sg = jax.lax.stop_gradient
    y0, y1, rate0, rate1 = sg(y0), sg(y1), sg(rate0), sg(rate1)
    dtype = y1.dtype
    inf = jnp.full((), jnp.inf, dtype)
    t0 = t1 - h
    alg = model.algebraic
    project, sigma = _maps(model, h, args)
    ends = jax.vmap(lambda t, y: _held(model, sigma, t, y))(
        jnp.stack([t0, t1]), jnp.stack([y0, y1])
    )
    held = ends[0] & ends[1]

    def at(c, on, J, j_rate):
        t = t0 + c * h
        y = jnp.where(alg, (1 - c) * y0 + c * y1, cubic_hermite(y0, y1, h * rate0, h * rate1, c))
        y_eq = _newton(model, sigma, on, J, t, y, args)
        y_set = jnp.where(held, project(t, y_eq), y_eq)
        outside = jnp.any(held & (jnp.abs(y_set - y_eq) > _band(y_eq)))
        drift = j_rate @ (y_eq - y_set)  # the rate's change, to first order
        return jnp.where(outside, jnp.max(jnp.abs(drift)), 0.0), outside

    def samples(_):
        # One linearisation, at the step's end, serves every sample.
        on, J, j_rate = _linearisation(model, sigma, held, t1, y1, args)
        c = jnp.arange(1, SAMPLES + 1, dtype=dtype) / (SAMPLES + 1)
        sampled = lambda _: jax.vmap(lambda c: at(c, on, J, j_rate))(c)  # noqa: E731
        return jax.lax.cond(jnp.any(on), sampled, nothing, None)

    def nothing(_):
        return jnp.zeros((SAMPLES,), dtype), jnp.zeros((SAMPLES,), bool)

    # Most steps hold nothing at both ends: skip the samples (a select under vmap).
    drift, outside = jax.lax.cond(jnp.any(held), samples, nothing, None)
    drift = jnp.where(jnp.isfinite(drift), drift, 0.0)
    violation = jnp.where(h > 0, h * jnp.max(drift), 0.0)
    first = jnp.argmax(outside)
    time = jnp.where(jnp.any(outside), first / (SAMPLES + 1) * h, inf)
    return sg(violation.astype(dtype)), sg(time.astype(dtype))


def held_start(model, t0, h, y0, args):
    r"""`y0` with every held selection row (see the module) replaced by the projection of
    its equivalent control at $t_0$: the right-limit selection of the phase. The
    multiplier a step ends with is the one its scheme needed, not the phase's: the
    trapezoidal rule solves $w_1 = u_0 + u_1 - w_0$ in a sliding mode of
    $x' = -w + u(t)$, so an error in $w_0$ comes back with its sign flipped at every step
    (measured on a forced relay: `max_steps` exhausted at rtol 1e-5). With the equivalent
    control at the start, $w_1 = u_1$. Where the equivalent control lies outside the set
    (the phase ends at $t_0$: the flow leaves the constraint), its projection is the
    selection of the side the flow goes to. A held row that no first-order constraint
    determines (a second-order sliding mode) starts on the surface's first derivative with
    its second-order equivalent control, where the step can reach it
    (`_on_second_order_surface_within`)."""
    project, sigma = _maps(model, h, args)
    held = _held(model, sigma, t0, y0)

    def start(y0):
        on, J, _ = _linearisation(model, sigma, held, t0, y0, args)
        y_eq = _newton(model, sigma, on, J, t0, y0, args)
        near = _on_second_order_surface_within(model, sigma, held & ~on, t0, h, y_eq, args)
        y_eq = on_second_order_surface(model, t0, t0, y_eq, t0 + h, y_eq, y_eq, args, near)
        y_start = jnp.where(held, project(t0, y_eq), y0)
        y_start = jnp.where(model.algebraic, y_start, y_eq)
        return jnp.where(jnp.all(jnp.isfinite(y_start)), y_start, y0)

    return jax.lax.cond(jnp.any(held), start, lambda y0: y0, y0)


def _on_second_order_surface_within(model, sigma, rows, t0, h, y, args):
    r"""The held rows among `rows` (no first-order hidden constraint: a second-order
    sliding mode, super-twisting's $w$ on $\sigma = 0$) whose surface's first derivative
    the selection can cancel within a step of size `h`:
    $|\dot\sigma| \le h \sum_j |\partial\ddot\sigma / \partial w_j|$ (sets of radius 1).
    There the step starts on the second-order surface with its equivalent control
    (`held_start`). The trapezoidal rule solves $w_1 = 2\bar w - w_0$, and a start off the
    surface (the bound the last switching left in $w$, and $\dot\sigma$ with it) came back
    with its sign flipped at every step, undamped: on super-twisting ($c = 3$, $L = 5$,
    rtol 1e-3) $w$ rang between 0.45 and -0.99 and $\dot\sigma$ at $\pm 3\cdot10^{-5}$
    after the convergence, and the steps fell to $10^{-5}$ until `max_steps`. A crossing
    of the surface while the state twists toward it ($\dot\sigma$ = 0.27 there) is not
    within reach: the guard follows the step the error control chose."""
    y = jax.lax.stop_gradient(y)
    first, second = _along_the_flow(model, sigma, t0, args)

    def within(_):
        reach = jnp.sum(jnp.abs(jnp.where(rows[None, :], jax.jacfwd(second)(y), 0.0)), axis=1)
        return rows & (jnp.abs(first(y)) <= h * reach)

    return jax.lax.cond(jnp.any(rows), within, lambda _: rows, None)


def phase_begins(model, t0, y0, t1, y1, args):
    """Whether a selection row is held at the end of the step from `(t0, y0)` to
    `(t1, y1)` and not at its start: a sliding mode or a stick begins inside the step (or
    on its end)."""
    h = jnp.where(t1 > t0, t1 - t0, 1.0)
    _, sigma = _maps(model, h, args)
    return jnp.any(~_held(model, sigma, t0, y0) & _held(model, sigma, t1, y1))


def second_order_ends(model, t0, y0, t1, y1, args):
    r"""`(y0, y1)` with each selection row that is held at both ends of the step from
    `(t0, y0)` to `(t1, y1)` but that no first-order hidden constraint determines (see
    `_linearisation`: a second-order sliding mode, super-twisting's $w$ with
    $\nu' = -k_2 w$, $\sigma = \sigma' = 0$) replaced at each end by its second-order
    equivalent control: one Newton step on $\ddot\sigma(w) = 0$, the surface's second
    derivative along the flow with the selection held (`_second_order_newton`). The rates
    an interpolant reads at the ends then follow the phase, not the stage: the trapezoidal
    rule solves $w_1 = 2\bar w - w_0$ there, so its end values ring from step to step
    (measured on super-twisting after its finite-time convergence, rtol 1e-5: $w$ off by
    about 0.4 at the ends, the cubic through the end rates of $\nu$ 400 times further off
    at `t_eval` than the steps). Other rows, and rows whose step is not held at both ends,
    unchanged."""
    h = jnp.where(t1 > t0, t1 - t0, 1.0)
    _, sigma = _maps(model, h, args)
    free = _second_order_rows(model, sigma, t0, y0, t1, y1, args)

    def ends(_):
        e0 = _second_order_newton(model, sigma, free, t0, y0, args)
        e1 = _second_order_newton(model, sigma, free, t1, y1, args)
        return e0, e1

    return jax.lax.cond(jnp.any(free), ends, lambda _: (y0, y1), None)


def second_order_rows(model, t0, y0, t1, y1, args):
    """The selection rows `on_second_order_surface` corrects in the step from `(t0, y0)`
    to `(t1, y1)` (held at both ends, no first-order hidden constraint): a quantity of the
    step, computed once for all the output times inside it."""
    h = jnp.where(t1 > t0, t1 - t0, 1.0)
    _, sigma = _maps(model, h, args)
    return _second_order_rows(model, sigma, t0, y0, t1, y1, args)


def on_second_order_surface(model, t, t0, y0, t1, y1, y, args, free):
    r"""`y` (the state interpolated at `t` inside the step from `(t0, y0)` to `(t1, y1)`)
    moved onto the surface's first derivative where a second-order sliding mode holds
    at both ends (`second_order_ends`): there $\sigma = \dot\sigma = 0$ along the
    phase, and $\dot\sigma(t, x)$ depends on the differential states alone, so it is a
    constraint on them at every instant, which the steps keep (super-twisting:
    $\nu = -d(t) - c\,x_2$) and a cubic through the ends does not: $\nu$ follows the
    disturbance, and over a step that $\sigma = 0$ makes long the cubic is off by
    $h^4 |\nu^{(4)}| / 384$ (measured: 20 times the steps' error, Bathe at rtol 1e-3).

    One Newton step on $\dot\sigma(t, x + B\lambda) = 0$, $B$ the rates' dependence on
    the selections ($\partial \dot x / \partial w$) on the rows the surface does not
    read (super-twisting's $\nu$; the rows it reads follow the cubic, which keeps
    $\sigma = 0$ to its order); then the selections take the second-order equivalent
    control at the corrected state (`_second_order_newton`). Kept only where that
    control lies inside its set (the phase holds at `t`) and everything is finite;
    `y` elsewhere, and on every other row. `free`: `second_order_rows` of the step."""
    h = jnp.where(t1 > t0, t1 - t0, 1.0)
    project, sigma = _maps(model, h, args)

    def correct(y):
        moved, ok = _onto_first_derivative(model, free, t, y, args)
        # The selections' value only (their derivatives the interpolated ones): the
        # capped slope of sqrt|sigma| at sigma = 0 makes the second-order control's
        # derivatives meaningless (measured with them kept in `second_order_ends`:
        # d x1 / d k2 at t_eval 55 where finite differences give 3e-3, trapezoidal rule).
        w_eq = _second_order_newton(model, sigma, free, t, moved, args)
        on_set = moved + jax.lax.stop_gradient(w_eq - moved)
        inside = jnp.all(~free | (jnp.abs(project(t, on_set) - on_set) <= _band(on_set)))
        ok = ok & inside & jnp.all(jnp.isfinite(on_set))
        return jnp.where(ok, on_set, y)

    return jax.lax.cond(jnp.any(free), correct, lambda y: y, y)


def _onto_first_derivative(model, free, t, y, args):
    # `(y, ok)`: `y` moved onto the surfaces of the rows `free` and their first
    # derivatives along the flow (selections held, their rate 0), one Newton step each:
    # the surface's rows of f (a held row's projection is a translation, so sigma =
    # -rho f there; f itself has no round-off of w - P(w + rho f)). First the
    # differential rows the surface reads, along its gradient (the least change:
    # sqrt|sigma| terms, as super-twisting's, blow up the interpolant's small sigma); then
    # the other differential rows, along the selections' columns of the rate's Jacobian.
    # The Jacobians carry no gradient (`_newton_step`): derivatives are those of the
    # projection onto the constraints.
    sg = jax.lax.stop_gradient
    diff = ~model.algebraic
    one = jnp.ones_like(t)

    def surface(yy):
        return jnp.where(free, model.f(t, yy, args), 0.0)

    def first(yy):
        rate = jnp.where(model.algebraic, 0.0, _rate(model, t, yy, args))
        return jax.jvp(
            lambda tt, y2: jnp.where(free, model.f(tt, y2, args), 0.0), (t, yy), (one, rate)
        )[1]

    g = jnp.where(free[:, None] & diff[None, :], jax.jacfwd(surface)(sg(y)), 0.0)
    reads = jnp.any(g != 0, axis=0)
    mu, ok_mu = _newton_step(g @ g.T, surface(y), free)
    y = y - g.T @ mu
    B = jax.jacfwd(lambda yy: _rate(model, t, yy, args))(sg(y))
    B = jnp.where((diff & ~reads)[:, None] & free[None, :], B, 0.0)
    lam, ok_lam = _newton_step(jax.jacfwd(first)(sg(y)) @ B, first(y), free)
    return y - B @ lam, ok_mu & ok_lam


def _newton_step(J, r, rows):
    # `(step, ok)`: J^-1 r over `rows` (zero elsewhere), J restricted to them, and whether
    # it is finite. The inverse carries no gradient and is zero where not finite, so a
    # singular J gives no NaN in derivatives (reverse mode reaches it through `where`).
    pair = rows[:, None] & rows[None, :]
    eye = jnp.eye(r.shape[0], dtype=r.dtype)
    inv = _linalg.inverse(jax.lax.stop_gradient(jnp.where(pair, J, eye)))
    ok = jnp.all(jnp.isfinite(inv))
    step = jnp.where(ok, inv, 0.0) @ jnp.where(rows, r, 0.0)
    return jnp.where(rows, step, 0.0), ok


def _second_order_rows(model, sigma, t0, y0, t1, y1, args):
    # The selection rows held at both ends of the step whose multiplier no first-order
    # hidden constraint determines (at the end: `_linearisation`).
    held = _held(model, sigma, t0, y0) & _held(model, sigma, t1, y1)
    on, _, _ = _linearisation(model, sigma, held, t1, y1, args)
    return held & ~on


def _along_the_flow(model, sigma, t, args):
    # `(first, second)`: the first and second derivatives of sigma along the flow at time
    # `t` as functions of the state, the selections held (their rate taken 0).
    one = jnp.ones_like(t)

    def rate(tt, yy):
        return jnp.where(model.algebraic, 0.0, _rate(model, tt, yy, args))

    def first_at(tt, yy):
        return jax.jvp(sigma, (tt, yy), (one, rate(tt, yy)))[1]

    def second(yy):
        return jax.jvp(first_at, (t, yy), (one, rate(t, yy)))[1]

    return (lambda yy: first_at(t, yy)), second


def _second_order_newton(model, sigma, rows, t, y, args):
    # One Newton step on the second derivative of sigma along the flow (selections held:
    # their rate taken 0) over `rows`, from `y`; the result where finite, else `y`.
    y = jax.lax.stop_gradient(y)
    _, second = _along_the_flow(model, sigma, t, args)
    J = jax.jacfwd(second)(y)
    pair = rows[:, None] & rows[None, :]
    eye = jnp.eye(y.shape[0], dtype=y.dtype)
    step = _linalg.solve_or_nan(jnp.where(pair, J, eye), jnp.where(rows, second(y), 0.0))
    out = jnp.where(rows, y - step, y)
    return jnp.where(jnp.all(jnp.isfinite(out)), out, y)


def _maps(model, h, args):
    # The projection of a state onto the sets, and the rows of y - P(y - rho R) of the
    # instantaneous residual R (-f on algebraic rows, 0 on differential ones), with the
    # stage's scaling rho for a step of size h.
    alg = model.algebraic
    safe_h = jnp.where(h > 0, h, 1.0)
    rho = jnp.where(alg, model.tau / safe_h, safe_h)

    def context(t, y):
        return ProjectionContext(
            t=t, h=safe_h, y_prev=y, y_iter=y, rho=rho.astype(y.dtype), args=args
        )

    def project(t, y):
        return model.projector(y, context(t, y))

    def sigma(t, y):
        z = y + jnp.where(alg, rho * model.f(t, y, args), 0.0)
        return y - model.projector(z, context(t, y))

    return project, sigma


def _band(y):
    # How far a value may move under a projection and still count as unmoved.
    return 64 * jnp.finfo(y.dtype).eps * (1.0 + jnp.abs(y))


def _held(model, sigma, t, y):
    # Selection rows whose projected equation is a translation in their own value near
    # `y`: perturbations of the multiplier either way pass through the projection
    # unchanged, so sigma takes the same value at both (interior of the set); at a bound
    # one of them is clipped and sigma moves with the other.
    d = jnp.sqrt(jnp.finfo(y.dtype).eps) * (1.0 + jnp.abs(y))
    d = jnp.where(model.algebraic, d, 0.0)
    plus, minus = jax.vmap(lambda u: sigma(t, u))(jnp.stack([y + d, y - d]))
    same = jnp.abs(plus - minus) <= 1e-3 * d
    return model.selection_rows & same


def _linearisation(model, sigma, held, t, y, args):
    # `(on, J, j_rate)`: the held rows whose hidden constraint G(w) = d sigma / dt along the flow
    # determines their multiplier, and G's Jacobian in w, sigma_x . dx'/dw (without the
    # curvature of sigma along the flow), at (t, y); no gradient. A row takes part only
    # where G depends on the multipliers about as strongly as |sigma_x| |dx'/dw| allows:
    # in a second-order sliding mode (super-twisting: u = -k1 sqrt|s| w + nu,
    # nu' = -k2 w) w drives x' but hardly the first derivative of the surface, which only
    # the second determines; a Newton step on G then divides by sqrt|s| ~ 0 (measured on
    # 81 super-twisting runs: 17 failures and 1.5x the attempts without this rule, against
    # 10; c = 3, L = 5 at rtol 1e-2 ran into max_steps, see
    # tests/test_filippov_trust.py). `j_rate`: dx'/dw on the held columns.
    y = jax.lax.stop_gradient(y)
    diff = ~model.algebraic
    j_sigma = jnp.where(diff[None, :], jax.jacfwd(lambda yy: sigma(t, yy))(y), 0.0)
    j_rate = jnp.where(held[None, :], jax.jacfwd(lambda yy: _rate(model, t, yy, args))(y), 0.0)
    J = j_sigma @ j_rate
    reach = jnp.linalg.norm(j_sigma, axis=1) * jnp.max(jnp.linalg.norm(j_rate, axis=0))
    strength = jnp.max(jnp.abs(jnp.where(held[None, :], J, 0.0)), axis=1)
    on = held & (strength > DETERMINED * reach) & (reach > 0)
    return jax.lax.stop_gradient((on, J, j_rate))


def _rate(model, t, y, args):
    return model.to_state(model.f(t, y, args))


def _newton(model, sigma, on, J, t, y, args):
    # One Newton step on G(w) = 0 over the rows `on`, from `y`, with the Jacobian `J`
    # (exact for x' affine in w); other rows unchanged.
    g = jax.jvp(sigma, (t, y), (jnp.ones_like(t), _rate(model, t, y, args)))[1]
    pair = on[:, None] & on[None, :]
    eye = jnp.eye(y.shape[0], dtype=y.dtype)
    step = _linalg.solve_or_nan(jnp.where(pair, J, eye), jnp.where(on, g, 0.0))
    return jnp.where(on, y - step, y)


def selection_phases(model, t0, y0, t1, y1, args):
    """What `selections_inside` reads of the step from `(t0, y0)` to `(t1, y1)` alone
    (computed once for all the output times inside it): the selection rows held at its
    start and at its end, and the start of the free flow `_crossed` follows."""
    h = jnp.where(t1 > t0, t1 - t0, 1.0)
    _, sigma = _maps(model, h, args)
    held0, held1 = _held(model, sigma, t0, y0), _held(model, sigma, t1, y1)
    return held0, held1, _free_start(model, t0, y0, args)


def selections_inside(model, t, t0, y0, t1, y1, y, args, phases):
    r"""`y` (the state interpolated at `t` inside the step from `(t0, y0)` to `(t1, y1)`,
    `y0` its start as the steppers take it) with every selection row replaced by the
    selection the phase has at `t`, inside its set (the projector's value, the last
    operation: a relay's $|w| \le 1$ bit for bit):

    - held at both ends (a sliding mode, a stick): the projected equivalent control at
      `(t, y)` (one Newton step on $G(w) = 0$ from `y`: the same order as the
      interpolated differential states);
    - held at the start only (the phase ends inside): the equivalent control while it
      lies inside its set, the end's selection from where it leaves it;
    - not held at the start (a relay off its surface): the start's selection until the
      row's switching function $f_w$ (the sign a relay reads), followed along the free
      flow from the start (second order), changes sign; from there the end's selection,
      or the equivalent control if the end is held (a sliding mode reached inside).

    Equation rows and differential rows are returned unchanged. `phases`:
    `selection_phases` of the step."""
    h = jnp.where(t1 > t0, t1 - t0, 1.0)
    project, _ = _maps(model, h, args)
    held0, held1, start = phases
    # The hidden constraint read with the selection rows' scaling shrunk (G = 0 does not
    # depend on it where nothing clips): a state off the surface by the interpolant's
    # error, or after the phase ends, would clip the stage's resolvent and leave G
    # without its dependence on w (measured: a relay leaving sliding inside a step,
    # w = -0.993 where the equivalent control is -1.03).
    _, sigma_eq = _maps(model, h / EQUIVALENT_SCALE, args)
    on, J, _ = _linearisation(model, sigma_eq, held0 | held1, t, y, args)
    y_eq = _newton(model, sigma_eq, on, J, t, y, args)
    y_eq = jnp.where(jnp.isfinite(y_eq), y_eq, y)
    eq = project(t, y_eq)
    inside = jnp.abs(eq - y_eq) <= _band(y_eq)
    leaving = jnp.where(inside, eq, y1)
    crossed = _crossed(model, t, t0, y0, start, args)
    reaching = jnp.where(crossed, jnp.where(held1, eq, y1), y0)
    w = jnp.where(held0, jnp.where(held1, eq, leaving), reaching)
    w = jnp.where(model.selection_rows, w, y)
    return jnp.where(model.selection_rows, project(t, w), y)


def _free_start(model, t0, y0, args):
    # `(r0, a0, g0)` of the free flow from the start that `_crossed` follows: the rate, its
    # derivative along the flow (state units) and f there.
    r0 = _rate(model, t0, y0, args)
    a0 = model.to_state(
        jax.jvp(lambda tt, yy: model.f(tt, yy, args), (t0, y0), (jnp.ones_like(t0), r0))[1]
    )
    return r0, a0, model.f(t0, y0, args)


def _crossed(model, t, t0, y0, start, args):
    # Whether each row's f has changed sign between the start and `t` along the free flow
    # from the start (selections held at the start's; `start`: `_free_start`), to second
    # order in t - t0.
    r0, a0, g0 = start
    d = t - t0
    y_free = y0 + d * (r0 + 0.5 * d * a0)
    g = model.f(t, y_free, args)
    return jnp.sign(g) != jnp.sign(g0)
