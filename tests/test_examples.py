"""The demo's closed-form references terminate and are right (the README's main command runs
them; a Zeno loop there once made it hang)."""

import importlib.util
from pathlib import Path

import numpy as np


def _demo():
    path = Path(__file__).resolve().parents[1] / "examples" / "demo.py"
    spec = importlib.util.spec_from_file_location("nivpjax_demo", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_demo_ball_reference_handles_zeno():
    demo = _demo()
    g = 9.81
    # Free fall before the first impact.
    np.testing.assert_allclose(demo.ball_exact(0.3), [1 - g * 0.3**2 / 2, -g * 0.3], rtol=1e-14)
    # e = 0.5: impacts accumulate at t_inf = sqrt(2/g) (1 + 2e/(1-e)) = 1.35 < 1.5: at rest.
    np.testing.assert_array_equal(demo.ball_exact(1.5, e=0.5), [0.0, 0.0])
    # e = 0.8 at t = 1.5: after two impacts, in flight (not at rest).
    q, v = demo.ball_exact(1.5, e=0.8)
    assert 0 < q < 1 and v != 0
