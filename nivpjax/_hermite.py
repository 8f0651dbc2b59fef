"""The cubic Hermite interpolant of a step from its end values and rates."""


def cubic_hermite(y0, y1, m0, m1, c):
    """The cubic through `y0` at `c = 0` and `y1` at `c = 1` with slopes `m0`, `m1` in
    `c` (the rates times the step size), at the fraction `c` of the step."""
    # Written as y0 plus increments: a row that does not move over the step (y0 = y1,
    # zero slopes: a state held at a face) comes back bit for bit.
    return y0 + c**2 * (3 - 2 * c) * (y1 - y0) + c * (1 - c) ** 2 * m0 + c**2 * (c - 1) * m1
