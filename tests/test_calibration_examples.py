"""Smoke test of the calibration examples (`examples/calibrate_*.py`): each module imports,
and its model reproduces its synthetic data at the true parameters to within the noise
(the residual RMS is the noise level), so the fits start from a consistent problem. The
full fits (`python examples/calibrate_*.py`) are run by hand: their forward-mode Jacobians
inside Levenberg-Marquardt compile for minutes on a shared 2-core machine."""

import importlib.util
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest


jax.config.update("jax_enable_x64", True)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _load(name):
    sys.path.insert(0, str(EXAMPLES))
    spec = importlib.util.spec_from_file_location(f"_example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _exact(module, name):
    if name == "calibrate_ball":
        return module.ball_state(module.TIMES, 1.0, 0.0, module.TRUTH["e"], 9.81)[0]
    if name == "calibrate_slider":
        p = dict(module.FIXED, **module.TRUTH)
        return module.slider_event_driven(p, 0.0, 0.0, 12.0, module.TIMES)[0]
    if name == "calibrate_rectifier":
        return module.exact(module.TIMES)
    k1, k2 = module.TRUTH["k1"], module.TRUTH["k2"]
    x0 = np.asarray(module.x0)
    return module.super_twisting_reference(x0, k1, k2, 1.0, module.TIMES)[0][:, :2]


@pytest.mark.parametrize(
    "name",
    ["calibrate_ball", "calibrate_slider", "calibrate_rectifier", "calibrate_sliding_mode"],
)
def test_example_model_matches_its_data_at_the_truth(name):
    module = _load(name)
    exact = np.asarray(_exact(module, name))
    truth = {k: jnp.asarray(v) for k, v in module.TRUTH.items()}
    residuals = np.asarray(jax.jit(module.residuals)(truth, jnp.asarray(exact)))
    scale = np.max(np.abs(exact))
    # The model error at the truth is well below the noise the examples add.
    assert np.sqrt(np.mean(residuals**2)) < 0.3 * module.SIGMA, (name, residuals)
    assert np.max(np.abs(residuals)) < 0.05 * scale
