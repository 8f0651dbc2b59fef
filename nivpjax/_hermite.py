"""The cubic Hermite interpolant of a step from its end values and rates."""


def cubic_hermite(y0, y1, m0, m1, c):
    """The cubic through `y0` at `c = 0` and `y1` at `c = 1` with slopes `m0`, `m1` in
    `c` (the rates times the step size), at the fraction `c` of the step."""
    return (
        (1 + 2 * c) * (1 - c) ** 2 * y0
        + c * (1 - c) ** 2 * m0
        + c**2 * (3 - 2 * c) * y1
        + c**2 * (c - 1) * m1
    )
