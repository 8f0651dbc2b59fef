"""With `event_margin=None` the margin by which steps land before a predicted event follows
the tolerance: the default fixed 1e-8 floors a bouncing ball's error at about 1e-7 for
every rtol (issue 24)."""

import jax
import numpy as np
import pytest

import nivpjax as nj
from nivpjax._controller.events import event_margin


G, E = 9.81, 0.8


def ball_exact(t_end, q=1.0, v=0.0):
    """The ball dropped from (q, v): flights between impacts, Newton's law at each."""
    t = 0.0
    while True:
        t_hit = (v + np.sqrt(v**2 + 2 * G * q)) / G
        if t + t_hit > t_end:
            dt = t_end - t
            return np.array([q + v * dt - 0.5 * G * dt**2, v - G * dt])
        t, v, q = t + t_hit, -E * (v - G * t_hit), 0.0


def test_default_margin_follows_rtol_and_an_explicit_one_is_kept():
    assert float(event_margin(None, 1e-4)) == 1e-8
    assert float(event_margin(None, 1e-6)) == 1e-8  # unchanged down to rtol 1e-6
    assert float(event_margin(None, 1e-8)) == pytest.approx(1e-10)
    assert event_margin(2e-7, 1e-8) == 2e-7
    # Not the default (a friction-reversal derivative at rtol 1e-8 came out 14% off with
    # it, fixed since: tests/test_reversal_gradients.py).
    assert nj.PIDController().event_margin == 1e-8


def test_ball_error_falls_with_rtol():
    """Against the exact ball after three impacts: from rtol 1e-4 to 1e-8 the error falls
    at least 100-fold (measured 1.1e-7 to 8.3e-10; with the fixed margin it stayed at
    1.1e-7), and to 1e-10 at least 10^4-fold (3.3e-12), with one compiled program
    (tolerances are run-time values)."""
    scene, x0, args = nj.scenes.bouncing_ball(restitution=E, gravity=G)

    @jax.jit
    def final(rtol):
        controller = nj.PIDController(rtol=rtol, atol=1e-2 * rtol, event_margin=None)
        return scene.solve(0.0, 1.5, x0, args, controller=controller).y_final

    exact = ball_exact(1.5)
    errors = [np.abs(np.asarray(final(rtol)) - exact).max() for rtol in (1e-4, 1e-8, 1e-10)]
    assert errors[1] * 100 <= errors[0] and errors[2] * 1e4 <= errors[0], errors
