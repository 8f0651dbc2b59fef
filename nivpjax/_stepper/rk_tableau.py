r"""Explicit Runge–Kutta pairs with a continuous extension, as plain coefficients."""

import equinox as eqx
import numpy as np


class ExplicitPair(eqx.Module):
    r"""An explicit Runge–Kutta pair: nodes $c$, the strictly lower-triangular matrix $a$,
    the propagated weights $b$ (order `order`), the error weights $b - \hat b$ ($\hat b$
    of order `order - 1`), whether the last stage is evaluated at the new point (first
    same as last), and the continuous extension: `dense(theta)`, the weights
    $b_i(\theta)$ with $y(t_0 + \theta h) \approx y_0 + h \sum_i b_i(\theta) k_i$, of order
    `dense_order`."""

    # Nested tuples (hashable: a stepper is part of a compiled program's structure).
    c_: tuple = eqx.field(static=True)
    a_: tuple = eqx.field(static=True)
    b_: tuple = eqx.field(static=True)
    b_error_: tuple = eqx.field(static=True)
    dense_: tuple = eqx.field(static=True)
    order: int = eqx.field(static=True)
    dense_order: int = eqx.field(static=True)

    @classmethod
    def of(cls, c, a, b, b_error, dense, order, dense_order):
        as_tuple = lambda x: tuple(np.asarray(x, float).tolist())  # noqa: E731
        rows = lambda x: tuple(as_tuple(r) for r in np.asarray(x, float))  # noqa: E731
        return cls(
            as_tuple(c), rows(a), as_tuple(b), as_tuple(b_error), rows(dense), order, dense_order
        )

    @property
    def c(self):
        return np.asarray(self.c_)

    @property
    def a(self):
        return np.asarray(self.a_)

    @property
    def b(self):
        return np.asarray(self.b_)

    @property
    def b_error(self):
        return np.asarray(self.b_error_)

    @property
    def dense_coefficients(self):
        return np.asarray(self.dense_)

    @property
    def stages(self) -> int:
        return len(self.c_)

    def dense(self, theta):
        r"""$b_i(\theta)$, shape `theta.shape + (stages,)`: the continuous extension's
        weights, polynomials in $\theta$ with $b_i(0) = 0$ and $b_i(1) = b_i$."""
        powers = [theta ** (k + 1) for k in range(self.dense_coefficients.shape[1])]
        out = 0.0
        for k, p in enumerate(powers):
            out = out + p[..., None] * self.dense_coefficients[:, k]
        return out


def _dormand_prince():
    # Dormand & Prince (1980), "A family of embedded Runge-Kutta formulae", the 5(4) pair
    # DOPRI5 with first same as last; the continuous extension of order 4 is Shampine's
    # (1986), written in Hairer, Norsett & Wanner (vol. I, II.6) as
    #   y(theta) = y0 + theta (r1 + (1 - theta)(r2 + theta (r3 + (1 - theta) r4))),
    #   r1 = y1 - y0, r2 = h k1 - r1, r3 = r1 - h k7 - r2, r4 = h sum_i d_i k_i.
    c = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0])
    a = np.zeros((7, 7))
    a[1, :1] = [1 / 5]
    a[2, :2] = [3 / 40, 9 / 40]
    a[3, :3] = [44 / 45, -56 / 15, 32 / 9]
    a[4, :4] = [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729]
    a[5, :5] = [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656]
    a[6, :6] = [35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84]
    b = a[6].copy()
    b_hat = np.array(
        [5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40]
    )
    d = np.array(
        [
            -12715105075 / 11282082432,
            0.0,
            87487479700 / 32700410799,
            -10690763975 / 1880347072,
            701980252875 / 199316789632,
            -1453857185 / 822651844,
            69997945 / 29380423,
        ]
    )
    # Expand the nested form into powers theta^1..theta^4 per stage weight. With
    # e1 = unit weight on k1, e7 on k7: r1 = b, r2 = e1 - b, r3 = 2 b - e1 - e7, r4 = d.
    # y = y0 + h [ theta r1 + theta (1-theta) r2 + theta^2 (1-theta) r3
    #              + theta^2 (1-theta)^2 r4 ].
    e1 = np.eye(7)[0]
    e7 = np.eye(7)[6]
    r1, r2, r3, r4 = b, e1 - b, 2 * b - e1 - e7, d
    coefficients = np.stack(
        [
            r1 + r2,  # theta
            -r2 + r3 + r4,  # theta^2
            -r3 - 2 * r4,  # theta^3
            r4,  # theta^4
        ],
        axis=1,
    )
    return ExplicitPair.of(c, a, b, b - b_hat, coefficients, order=5, dense_order=4)


DOPRI5 = _dormand_prince()
