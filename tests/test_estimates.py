"""Embedded error estimates against the true local error of one step.

The reference is an independent solver (diffrax Tsit5 at tolerance 1e-13) from the same
start: on a smooth forced Duffing-type oscillator the estimate of every built-in stepper
must track the true local error over a ladder of step sizes, and both must converge with
the stepper's error order.
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj
from nivpjax._model import Model


def field(t, y, args):
    return jnp.stack([y[1], -y[0] - 0.1 * y[1] ** 3 + jnp.sin(2 * t)])


T0 = 0.2
Y0 = jnp.array([1.0, 0.3])
HS = np.array([0.2, 0.1, 0.05, 0.025])
MODEL = Model(
    vector_field=field, projector=nj.Identity(), mass_matrix=None, algebraic=jnp.zeros(2, bool)
)
TIGHT = nj.SemismoothNewton(rtol=1e-13, atol=1e-14)


@jax.jit
def _exact(h):
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field),
        diffrax.Tsit5(),
        T0,
        T0 + h,
        None,
        Y0,
        stepsize_controller=diffrax.PIDController(rtol=1e-13, atol=1e-13),
        max_steps=10_000,
    )
    return sol.ys[-1]


@pytest.fixture(scope="module")
def exact():
    return {h: np.asarray(_exact(jnp.asarray(h))) for h in HS}


# (stepper, local-error order, band of est/true over the ladder, measured in brackets)
CASES = {
    "be": (nj.BackwardEuler(TIGHT), 2),  # ratios 1.06 -> 1.00
    "tr": (nj.Trapezoidal(TIGHT), 3),  # 1.22 -> 1.03
    "theta0.7": (nj.Theta(0.7, TIGHT), 2),  # 1.17 -> 1.01
    "bathe": (nj.Bathe(solver=TIGHT), 3),  # 1.00
    "trbdf2": (nj.Bathe(2 - np.sqrt(2), TIGHT), 3),  # 1.02 -> 1.00
}


@pytest.mark.parametrize("name", list(CASES))
def test_estimate_tracks_local_error(name, exact):
    stepper, order = CASES[name]
    assert stepper.error_order == order
    step = jax.jit(lambda h: stepper.step(MODEL, jnp.asarray(T0), h, Y0, None))
    true, est = [], []
    for h in HS:
        out = step(jnp.asarray(h))
        true.append(np.linalg.norm(np.asarray(out.y1) - exact[h]))
        est.append(np.linalg.norm(np.asarray(out.y_error)))
    true, est = np.array(true), np.array(est)
    ratio = est / true
    assert np.all((0.8 <= ratio) & (ratio <= 1.35)), ratio
    assert 0.9 <= ratio[-1] <= 1.1, ratio  # asymptotically exact
    # Orders from the two smallest steps: the true error's and the estimate's.
    for e in (true, est):
        measured = np.log2(e[-2] / e[-1])
        assert abs(measured - order) <= 0.2, (measured, order)
