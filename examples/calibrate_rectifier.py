"""Calibration: the smoothing capacitance and the load of a half-wave diode rectifier, from
a noisy record of the load voltage.

The circuit (`nivpjax.scenes.half_wave_rectifier`): a 50 Hz source of 1 V, an ideal diode
with 1 ohm in series, and an RC load (truth C = 0.1 mF, R_L = 1 kohm). The diode conducts
near each peak of the source and the capacitor discharges through the load in between.
Observations: v(t) at 80 times over three periods from the exact piecewise solution
(diode switches by Brent's method), with Gaussian noise of 2 mV.

The fit (`nivpjax.fit`, Levenberg-Marquardt, Jacobian through the solver) starts 40% off
on both parameters (C = 0.06 mF, R_L = 1.4 kohm). The diode switches are located by the
step-size control; the current is continuous across them, so no event-time term is
missing.

Run:  python examples/calibrate_rectifier.py   (writes examples/output/calibrate_rectifier.png)
"""

import os


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _calibration import figure, noisy, observe, report  # noqa: E402
from _references_switching import RectifierReference, output_path  # noqa: E402

import nivpjax as nj  # noqa: E402


jax.config.update("jax_enable_x64", True)

TRUTH = {"C_mF": 0.1, "R_L_kohm": 1.0}
T1 = 0.06
TIMES = np.linspace(0.001, T1, 80)
SIGMA = 0.002
scene, x0, args = nj.scenes.half_wave_rectifier()


def voltage(params, times):
    a = dict(args, C=params["C_mF"] * 1e-3, R_L=params["R_L_kohm"] * 1e3)
    return observe(scene, T1, x0, a, times)[:, 0]


def residuals(params, data):
    return voltage(params, jnp.asarray(TIMES)) - data


def exact(times):
    ref = RectifierReference(1.0, 2 * np.pi * 50, 1.0, 1e3, 1e-4, T1, full=False)
    return ref.v(times)


def main():
    data = jnp.asarray(noisy(exact(TIMES), SIGMA))
    start = {"C_mF": jnp.asarray(0.06), "R_L_kohm": jnp.asarray(1.4)}
    run = jax.jit(lambda p, d: nj.fit(residuals, p, d), compiler_options=nj.compiler_options())
    t0 = time.perf_counter()
    fit = jax.block_until_ready(run(start, data))
    print(f"compile + fit: {time.perf_counter() - t0:.1f} s")
    worst = report(list(TRUTH), TRUTH, start, fit)
    grid = np.linspace(0.0005, T1, 600)
    fitted = np.asarray(jax.jit(voltage)(fit.params, jnp.asarray(grid)))
    figure(
        output_path("calibrate_rectifier.png"),
        f"C = {float(fit.params['C_mF']):.4f} mF, R_L = {float(fit.params['R_L_kohm']):.4f} kohm",
        TIMES,
        data,
        grid,
        {"fit": fitted, "truth": exact(grid)},
        {"start 40% off": fit.history},
        "load voltage v",
    )
    return worst


if __name__ == "__main__":
    assert main() < 0.02
