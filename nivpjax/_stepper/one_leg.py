"""The theta family: backward Euler, trapezoidal, and any theta in [1/2, 1]."""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._nonlinear import AbstractNonlinearSolver
from .._projector import Identity
from .base import AbstractStepper, StepOutput, default_solver, stats_of
from .departure import held_row_errors


def state_rate(model, t, y, F, y0, y1, h, switched, args):
    """The rate at `(t, y)` in state units, from `F` in the units of $f$. Algebraic rows
    (multipliers) get their secant rate over the step, so that a multiplier sliding along
    an equivalent control is seen as moving, unless the selection changed face in the
    step (`switched`): a jump of the multipliers is not smooth flow, and the secant would
    explain it away. Equation rows (index-1) get their own rate at `(t, y)` instead (see
    `Model.equation_rate`): a secant has the same value at both ends of the step, so the
    estimate would not see their rate change."""
    h_safe = jnp.where(h > 0, h, 1.0)
    secant = jnp.where(switched, 0.0, (y1 - y0) / h_safe)
    rate = jnp.where(model.algebraic, secant, model.to_state(F))
    return model.equation_rate(t, y, rate, args, rate)


def flow_derivative(model, t, y, rate, args):
    r"""$\frac{d}{dt} f(t, y(t)) = \partial_t f + J\,y'$ along the rate $y'$ (one JVP)."""
    one = jnp.ones_like(t)
    return jax.jvp(lambda tt, yy: model.f(tt, yy, args), (t, y), (one, rate))[1]


def theta_error(model, theta, t0, h, y0, y1, f0, f1, reaction, args):
    r"""The embedded local-error estimate of a theta step, in the units of $f$.

    With the stage reaction $r$ taken as constant over the step (it cancels in
    differences of the effective rates $F = f + r$):

    $$ e = (\theta - \tfrac12)\,h\,(f_1 - f_0)
           + \tfrac{h^2}{12}\,[\theta = \tfrac12]\,(\dot F_1 - \dot F_0), \quad
       D = f_1 - f_0 - \tfrac h2 (\dot F_0 + \dot F_1), $$

    where $\dot F = \partial_t f + J y'$, the multipliers' rates included (see
    `state_rate`). Like every estimate here, $e$ is the computed state minus the exact
    one: the first term is the leading local error $(\theta - \frac12) h^2 y''$, the
    second the trapezoidal rule's $+\frac{h^3}{12} y'''$. $D$ is the change of rate over
    the step that the smooth flow does not explain: $O(h^3)$ on a smooth piece, the jump
    of the rate when a selection changes face inside the step. A scheme that averages the
    end rates ($\theta < 1$) then makes an error of up to $(1 - \theta)\,h\,|D|$, which
    replaces $e$ per component where it is the larger. It is not added: on a smooth piece
    it is $-\tfrac{h^4}{24} y''''$ (for $\theta = \frac12$), a higher-order term of either
    sign, and where the step is not small against the distance to a singularity of the
    rate (a square root running into 0, super-twisting's $\sqrt{|\sigma|}$) it cancelled
    the leading term: 0.4 of the error at half that distance, a step accepted at 4.7
    times its tolerance. Backward Euler collocates the selection at the step's end; its
    first term already sees the jump through the multipliers in $f$.
    """
    if theta == 1.0:
        return backward_euler_error(model, t0, h, y0, y1, f0, f1, args)
    e = (theta - 0.5) * h * (f1 - f0)
    t1 = t0 + h
    switched = model.switched(t1, h, y0, y1, args)
    F0, r0, df0 = _effective(model, t0, h, y0, f0, reaction, y0, y1, switched, args)
    F1, r1, df1 = _effective(model, t1, h, y1, f1, reaction, y0, y1, switched, args)
    if theta == 0.5:
        e = e + h**2 / 12 * (df1 - df0)
    defect = (1 - theta) * h * (F1 - F0 - 0.5 * h * (df0 + df1))
    e = jnp.where(jnp.abs(defect) > jnp.abs(e), defect, e)
    kink = switch_kink_error(model, theta, t0, h, y0, y1, f0, f1, switched, args)
    return jnp.where(jnp.abs(kink) > jnp.abs(e), kink, e)


def _effective(model, t, h, y, f, reaction, y0, y1, switched, args):
    # `(F, rate, F_dot)` at one end of a theta step: the effective rate F = f + r, the
    # state rate, and F's derivative along it. The stage reaction r is constant over the
    # step, except on rows whose law the stage weighs at both ends (friction as a
    # proximal map, see `Model.law_reaction`): there r is the law's reaction at this end
    # and F_dot includes its derivative along the flow, so the estimate sees a reaction
    # that changes along a slip (a slip-weakening bound; the trapezoidal rule's estimate
    # was blind to it: 2.2x the smooth field's error at rtol 1e-7).
    if not model.has_weighed:
        rate = state_rate(model, t, y, f + reaction, y0, y1, h, switched, args)
        return f, rate, flow_derivative(model, t, y, rate, args)
    law, along = model.law_reaction_linearized(t, h, y, args)
    r = jnp.where(model.weighed, law, reaction)
    rate = state_rate(model, t, y, f + r, y0, y1, h, switched, args)
    # F differs from f on the weighed rows only: elsewhere r is constant over the step.
    F = jnp.where(model.weighed, f + r, f)
    return F, rate, flow_derivative(model, t, y, rate, args) + along(rate)


def switch_kink_error(model, theta, t0, h, y0, y1, f0, f1, switched, args):
    r"""The error of a theta step whose stage changed face (`switched`: friction sticking,
    a relay reaching its sliding set, a diode switching) at a time $\tau$ inside it: the
    rate has a kink or a jump there, and the scheme weighs the end rates as if it had
    none, $e = (1 - \theta)(h - \tau)(f_0 - f_1)$ (exact for a rate linear up to $\tau$
    and constant after). $\tau$ from `Model.next_event` where the projector predicts the
    event inside the step (a step landing on it is charged nothing), 0 otherwise.

    The defect term of `theta_error` charges the same where $f$ carries the switch
    (multipliers) or the stage weighs the law at both ends (friction as a proximal map,
    `Model.law_reaction`); this one is for laws without multipliers whose reaction the
    estimate takes as constant over the step, so that $D = 0$: a normal cone on a
    differential row (a velocity bound reached inside the step: the estimate was 0
    without this term, see `test_theta_estimate_charges_a_face_reached_inside_the_step`).
    Measured before friction was weighed: a block sliding to rest on a plane ended 1.8e-2
    off at every `rtol` with the trapezoidal rule, in eight steps, `successful`."""
    if isinstance(model.projector, Identity) or model.has_impulses:
        # Contacts have charges of their own (impacts at the step's start, landings);
        # a contact opening after an impact is no kink of the flow.
        return jnp.zeros_like(f0)
    tau = event_in_step(model, t0, h, y0, y1, args)
    return jnp.where(switched, (1 - theta) * (h - tau) * (f0 - f1), 0.0)


def late_switch_error(model, t0, h, y0, y1, f0, args):
    r"""`(f0_end, e)`: $\tilde f_0 = f(t_0, \tilde y_0)$, the start rate with the
    selections of the step's end (`Model.selection_rows`; equation rows keep their start
    values, which their equations fix), and the error of a backward Euler stage that
    applied them from the start although the selection changes face only at a time $\tau$
    inside the step (the first zero of a switching function, from `Model.next_event`):
    $e = \tau\,(f_0 - \tilde f_0)$, in the units of $f$. It is what rejects a step that
    crosses a switching surface, or lands on one, too early."""
    f0_end = model.f(t0, jnp.where(model.selection_rows, y1, y0), args)
    # Where the selection did not change, f0 = f0_end and the term vanishes anyway.
    tau = event_in_step(model, t0, h, y0, y1, args)
    return f0_end, tau * (f0 - f0_end)


def event_in_step(model, t0, h, y0, y1, args):
    """The predicted time from `t0` of the first event inside the step (`Model.next_event`
    from the step's own start `y0`), 0 where none is predicted inside it."""
    tau = model.next_event(t0 + h, h, y0, y1, args, started=True)
    # A step that lands on the surface has its event at the end, tau = h up to the
    # rounding of the secant (measured one ulp above h for a step jumping onto a sliding
    # set, which a strict `tau <= h` left uncharged: a successful run with its sliding
    # time off by 8e-4 at rtol 1e-5).
    return jnp.where(tau <= h * (1 + jnp.sqrt(jnp.finfo(y1.dtype).eps)), jnp.minimum(tau, h), 0.0)


def backward_euler_error(model, t0, h, y0, y1, f0, f1, args):
    r"""Backward Euler's estimate $\tfrac h2 (f_1 - \tilde f_0) + \tau\,(f_0 - \tilde f_0)$.

    The scheme never evaluates $f$ at the start, so the start rate is free to choose:
    $\tilde f_0 = f(t_0, \tilde y_0)$ takes the selections of the step's end,
    which is the right-limit rate when the step starts on a switching surface or inside a
    sliding mode (where the previous step's multiplier is an average over that step, not
    the selection at $t_0$). Equation rows (a diode's current through its series resistor)
    keep their start values: they are functions of the state, so that the estimate sees
    them move over the step (taking the end's put the whole change of a conducting diode's
    current out of sight: an estimate 1000x too small). A selection that changes face
    inside the step was applied too early: the second term, see `late_switch_error`."""
    if not model.has_algebraic:
        return 0.5 * h * (f1 - f0)
    f0_end, late = late_switch_error(model, t0, h, y0, y1, f0, args)
    # Neither start rate is right everywhere: f0_end is off by O(h) inside a sliding mode
    # (the end's equivalent control applied at t0: an estimate h^2/2 |w'| where the state's
    # true error is zero), f0 by O(1) after a landing step (whose multiplier is an average
    # over that step). Each is exact where the other fails; per component, the smaller
    # difference is the right-limit one.
    d_end, d_start = f1 - f0_end, f1 - f0
    base = jnp.where(jnp.abs(d_start) < jnp.abs(d_end), d_start, d_end)
    return 0.5 * h * base + late


def early_crossing(model, theta, t0, h, y0, f0, args):
    r"""Whether a theta step from `(t0, y0)` of size `h` is predicted to cross a switching
    surface at a time $\tau < (1 - \theta) h / 2$ ($h/4$ for the trapezoidal rule), along
    its start rate (`Model.next_event` on the explicit Euler prediction $y_0 + h\,y_0'$:
    exact for a rate that is constant up to the switch). Such a step is taken with
    $\theta = 1$ (backward Euler, with its own estimate).

    When the rate jumps from $f_0$ to $f_1$ at $\tau$ inside a step, the theta method's
    end value is off by $((1 - \theta) h - \tau)(f_0 - f_1)$ (it applies the old rate for
    $(1 - \theta) h$) and backward Euler's by $\tau\,(f_0 - f_1)$ (the new rate from the
    start): backward Euler is the nearer for $\tau < (1 - \theta) h / 2$. The theta
    method's error there also carries the state on along the old rate past the surface:
    where the controller steps over switchings within tolerance of a Filippov spiral's
    Zeno point, each such trapezoidal step pushed the state back out by up to its
    tolerance, and the spiral circled the origin at that distance until `max_steps`
    (S = 60, a = 0.1 with the VI method: a cycle of 1 029 steps, at every rtol from 1e-2
    to 1e-8); backward Euler's steps cut the corner towards the origin and land on it.
    A step that lands on a switch ($\tau = h$) keeps its theta."""
    y_pred = y0 + h * model.to_state(f0)
    tau = model.next_event(t0 + h, h, y0, y_pred, args, started=True)
    return tau < 0.5 * (1 - theta) * h


class _AbstractTheta(AbstractStepper):
    theta: eqx.AbstractVar[float]
    solver: eqx.AbstractVar[AbstractNonlinearSolver]

    @property
    def order(self) -> int:
        return 2 if self.theta == 0.5 else 1

    @property
    def error_order(self) -> int:
        return self.order + 1

    def step(self, model, t0, h, y0, args):
        t1 = t0 + h
        y0, f0, start_error = model.step_start(t0, h, y0, args)
        f_explicit = None if self.theta == 1.0 else f0
        theta, crossing = self.theta, None
        if self.theta < 1.0 and model.has_selections and not model.has_impulses:
            crossing = early_crossing(model, self.theta, t0, h, y0, f0, args)
            theta = jnp.where(crossing, 1.0, self.theta).astype(y0.dtype)
        sol, multipliers = model.solve_stage(
            self.solver, t1, h, y0, f_explicit, theta, y0, y0, args
        )
        y1 = sol.value
        f1 = model.f(t1, y1, args)
        reaction = model.reaction(multipliers)
        e = theta_error(model, self.theta, t0, h, y0, y1, f0, f1, reaction, args)
        e = model.to_state(e)
        if self.theta < 1.0:
            # Schemes that weigh the end rates (backward Euler's estimate is its own,
            # `backward_euler_error`).
            e = held_row_errors(model, t0, h, y0, y1, f0, f1, e, args)
        if crossing is not None:
            e_crossing = backward_euler_error(model, t0, h, y0, y1, f0, f1, args)
            e = jnp.where(crossing, model.to_state(e_crossing), e)
        return StepOutput(
            y1=y1,
            y_error=e + start_error,
            multipliers=multipliers,
            stats=stats_of(sol),
        )


class Theta(_AbstractTheta):
    r"""The theta method,
    $A(y_1 - y_0) = h[\theta f(t_1, y_1) + (1 - \theta) f(t_0, y_0)] + (\text{reaction})$,
    with algebraic rows collocated at $t_1$: $0 = f_{\text{alg}}(t_1, y_1)$ (averaging them
    would let multipliers oscillate from step to step).

    Order 2 for $\theta = 1/2$, 1 otherwise; A-stable for $\theta \ge 1/2$, L-stable only at
    $\theta = 1$. Embedded error estimate from the stage rates at no extra implicit solve
    (see `theta_error`; error order 2, or 3 for $\theta = 1/2$). A step predicted to cross
    a switching surface at $\tau < (1 - \theta) h / 2$ is taken with $\theta = 1$, whose
    error there is the smaller (see `early_crossing`).
    """

    theta: float = 1.0
    solver: AbstractNonlinearSolver = eqx.field(default_factory=default_solver)

    def __check_init__(self):
        if not 0.5 <= self.theta <= 1.0:
            raise ValueError(f"`theta` must lie in [1/2, 1], got {self.theta}.")


class BackwardEuler(_AbstractTheta):
    """Backward (implicit) Euler: the theta method with $\\theta = 1$. Order 1, L-stable;
    with a projector, Moreau–Jean time stepping. Embedded estimate
    $\\tfrac h2 (f_1 - f_0)$ (error order 2)."""

    solver: AbstractNonlinearSolver = eqx.field(default_factory=default_solver)

    @property
    def theta(self) -> float:
        return 1.0


class Trapezoidal(_AbstractTheta):
    """The trapezoidal rule: the theta method with $\\theta = 1/2$. Order 2, A-stable, no
    damping (multipliers may ring after a switch: prefer Bathe for that). Embedded
    estimate $\\tfrac{h^2}{12}(\\dot F_1 - \\dot F_0)$ plus a charge for rate jumps
    (error order 3). A step predicted to cross a switching surface in its first quarter
    is a backward Euler step (see `early_crossing`)."""

    solver: AbstractNonlinearSolver = eqx.field(default_factory=default_solver)

    @property
    def theta(self) -> float:
        return 0.5
