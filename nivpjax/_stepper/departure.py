"""The error of a step inside which a set lets go of a row it held at a face."""

import jax.numpy as jnp


def departure_error(model, t0, h, y0, y1, f0, f1, args):
    r"""The local error (state units) of a step over a departure from a face: a row a set
    held at the step's start (the vector field $f_0$ pushing it out of the set) whose field
    $f_1$ at the end points inside.

    With the rate $r = A^{-1} f$ linear over the step, the row left the face at
    $t_d = t_0 + h\,r_0 / (r_0 - r_1)$, and by $t_1$ the exact state moved
    $\int_{t_d}^{t_1} r = h\,r_1^2 / (2 (r_1 - r_0))$ off the face (the start's value), so

    $$ e = (y_1 - y_0) - \frac{h\,r_1^2}{2\,(r_1 - r_0)} $$

    on those rows, 0 elsewhere. Schemes that weigh the end rates miss it, and their
    estimates are blind to it: the trapezoidal rule projects $y_0 + \tfrac h2 (f_0 + f_1)$
    and ends on the face while $f_0$ still pushes out more than $f_1$ pulls in; Bathe's
    backward-difference stage starts from two points on the face and moves the row by
    $h f_1 / c_3$ (measured on Moreau's sweeping process: both 1.0-5.2x above the
    campaign's bound $C\,\mathrm{rtol}^{2/3}$, their errors falling like
    $\mathrm{rtol}^{1/2}$; `f` is smooth there and every stage lies on the face).
    `Model.projected_rate` reads which rows are held. Rows with impulses (contacts) and a
    proximal map's rows (friction) are not held at a face in this sense: 0 there
    (`Model.has_held_rows`)."""
    if not model.has_held_rows:
        return jnp.zeros_like(y1)
    rows = model.held_rows
    _, held = model.projected_rate(t0, h, y0, jnp.where(rows, f0, 0.0), args)
    _, held_end = model.projected_rate(t0 + h, h, y1, jnp.where(rows, f1, 0.0), args)
    r0, r1 = model.to_state(f0), model.to_state(f1)
    left = rows & held & ~held_end & (r0 * r1 < 0)
    span = jnp.where(left, r1 - r0, 1.0)
    return jnp.where(left, (y1 - y0) - 0.5 * h * r1 * r1 / span, 0.0)


def held_row_errors(model, t0, h, y0, y1, f0, f1, e, args):
    r"""A stepper's estimate `e` (state units) corrected on rows a set starts or stops
    holding inside the step. Rows that came to rest (friction sticking: a sliding
    velocity stuck at the end, `Model.arrest_error`) take the projector's arrest
    estimate: the stepper's measures the jump of their effective rate $f + r$, not an
    error of their value, which is exact where the slip had ended. Rows a face let go of
    take the `departure_error` where it is the larger."""
    if model.has_arrests:
        arrested, stop_error = model.arrest_error(t0 + h, h, y0, y1, f0, f1, args)
        e = jnp.where(arrested, stop_error, e)
    left = departure_error(model, t0, h, y0, y1, f0, f1, args)
    return jnp.where(jnp.abs(left) > jnp.abs(e), left, e)
