"""The benchmark scenes: nivpjax scene, horizon, exact reference and error norm.

Every case is a scene of `nivpjax.scenes` with an exact or trusted reference from
`examples/_references_*.py` (plain NumPy/SciPy, no nivpjax):

- `ball`: bouncing ball, H = 1, e = 0.8, g = 9.81, t in [0, 3] (six impacts; Zeno at 4.06).
  Closed form. Error: max-norm of the (q, v) error at t = 3. (A pointwise error along the
  trajectory is O(1) in v next to every impact for any method whose impact time is off by
  a little, so the final state is the informative norm here.)
- `slider`: undriven, undamped spring-slider with constant Coulomb friction mu = 0.2, m = k
  = N = 1, v0 = 0.9, t in [0, 10]: three slip phases, sticks for good at t = 7.635.
  Piecewise-harmonic closed form.
- `relay`: x' = -sign(x) + 0.5 sin(2 pi t), x0 = 0.5, t in [0, 2]: reaches x = 0 at
  t = 0.63 and slides (Filippov). Closed form.
- `super_twisting`: the super-twisting controller on a double integrator, x0 = (0.5, 0, 0),
  t in [0, 5] (twisting, finite-time reaching at T* = 2.136, then sliding). Event-driven
  DOP853 at rtol 1e-12 between the sign changes, closed form in sliding.
- `rectifier`: half-wave diode rectifier, 50 Hz, R_s = 1, R_L = 1k, C = 100 uF, three
  periods (t in [0, 0.06]); every method's step is bounded by h_max = 1 ms (T/20), without
  which loose tolerances step over conduction pulses (see examples/rectifier.py). Closed
  form per regime, switches by Brent's method.
- `chua`: Chua's circuit with the piecewise-linear diode sat(x) = clip(x, -1, 1), t in
  [0, 10] (eleven kink crossings; chaotic, so only a short horizon is meaningful).
  Region-wise DOP853 at rtol 1e-13 restarted on the kinks ("tight smooth reference").

Error (all but the ball): the largest max-norm error of the scene's states (multipliers
excluded) over the method's own accepted output points, against the reference at the same
times (no interpolation; all these states are continuous in time).
"""

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import nivpjax as nj


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
from _references_mechanics import (  # noqa: E402
    ball_state,
    slider_constant_friction,
    slider_constant_friction_state,
)
from _references_switching import (  # noqa: E402
    RectifierReference,
    chua_reference,
    relay_exact,
    super_twisting_reference,
)


@dataclass
class Case:
    name: str
    title: str
    make: object  # () -> (scene, x0, args)
    t1: float
    norm: str  # a one-line description of the error norm
    final_only: bool = False  # error of the final state only
    h_max: float | None = None  # step bound for every method
    controller: dict = field(default_factory=dict)

    def build(self):
        scene, x0, args = self.make()
        return scene, np.asarray(x0), {k: float(v) for k, v in args.items()}

    def exact(self, ts):
        """Exact states at the times `ts` (sorted 1-D array): shape (len(ts), n_states)."""
        _, x0, p = self.build()
        ts = np.asarray(ts, float)
        return EXACT[self.name](ts, x0, p, self.t1)


def _ball_exact(ts, x0, p, t1):
    q, v = ball_state(ts, x0[0], x0[1], p["e"], p["g"])
    return np.stack([q, v], axis=-1)


def _slider_exact(ts, x0, p, t1):
    assert p["V"] == 0 and p["c"] == 0 and p["mu_s"] == p["mu_k"]
    phases, _ = slider_constant_friction(x0[0], x0[1], p["m"], p["k"], p["mu_k"], p["N"], t1)
    s, v = slider_constant_friction_state(ts, phases, p["m"], p["k"], p["mu_k"], p["N"])
    return np.stack([s, v], axis=-1)


def _relay_exact(ts, x0, p, t1):
    x, _, _ = relay_exact(ts, p["amplitude"], p["frequency"], x0[0])
    return x[:, None]


def _st_exact(ts, x0, p, t1):
    grid = np.unique(np.append(ts, t1))
    states, _, _ = super_twisting_reference(x0, p["k1"], p["k2"], p["c"], grid)
    return states[np.searchsorted(grid, ts)]


def _rect_exact(ts, x0, p, t1):
    ref = _rect_reference(p, t1)
    return ref.v(ts)[:, None]


_RECT_CACHE = {}


def _rect_reference(p, t1):
    key = (tuple(sorted(p.items())), t1)
    if key not in _RECT_CACHE:
        _RECT_CACHE[key] = RectifierReference(
            p["V"], p["omega"], p["R_s"], p["R_L"], p["C"], t1, full=False
        )
    return _RECT_CACHE[key]


def _chua_exact(ts, x0, p, t1):
    grid = np.unique(np.append(ts, t1))
    states, _ = chua_reference(x0, grid, p["alpha"], p["beta"], p["m0"], p["m1"])
    return states[np.searchsorted(grid, ts)]


EXACT = dict(
    ball=_ball_exact,
    slider=_slider_exact,
    relay=_relay_exact,
    super_twisting=_st_exact,
    rectifier=_rect_exact,
    chua=_chua_exact,
)

_NODES = "max over the method's accepted points of the max-norm state error"

CASES = {
    c.name: c
    for c in [
        Case(
            "ball",
            "Bouncing ball (e = 0.8, H = 1, t <= 3, 6 impacts)",
            lambda: nj.scenes.bouncing_ball(restitution=0.8, height=1.0),
            3.0,
            "max-norm error of (q, v) at t = 3",
            final_only=True,
        ),
        Case(
            "slider",
            "Spring-slider, Coulomb friction (mu = 0.2, v0 = 0.9, t <= 10, sticks at 7.64)",
            lambda: nj.scenes.spring_slider(mu_static=0.2, mu_kinetic=0.2, velocity=0.9),
            10.0,
            _NODES + " (s, v)",
        ),
        Case(
            "relay",
            "Relay with disturbance, Filippov sliding (t <= 2)",
            lambda: nj.scenes.relay(),
            2.0,
            _NODES + " (x)",
        ),
        Case(
            "super_twisting",
            "Super-twisting controller (t <= 5, reaching at 2.136)",
            lambda: nj.scenes.super_twisting(),
            5.0,
            _NODES + " (x1, x2, nu)",
        ),
        Case(
            "rectifier",
            "Half-wave diode rectifier (3 periods of 50 Hz, h_max = 1 ms)",
            lambda: nj.scenes.half_wave_rectifier(),
            0.06,
            _NODES + " (v, volts)",
            h_max=1e-3,
        ),
        Case(
            "chua",
            "Chua's circuit, piecewise-linear diode (t <= 10)",
            lambda: nj.scenes.chua(),
            10.0,
            _NODES + " (x, y, z)",
        ),
    ]
}
