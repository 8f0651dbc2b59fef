"""Calibration: the restitution coefficient of a bouncing ball from noisy heights.

Observations: the height q(t) of a ball dropped from 1 m (e = 0.8, g = 9.81), at 40 times
over three bounces, with Gaussian noise of 1 cm. Model: `nivpjax.scenes.bouncing_ball`
solved by Bathe's scheme at rtol 1e-6 (step capped at 0.02 s so that the piecewise-linear
output interpolation stays below the noise). The fit (`nivpjax.fit`: Levenberg-Marquardt,
Jacobian by forward-mode autodiff through the solver, impact-time sensitivities included)
starts from e = 0.5 (37% off) and reports the estimate with its Gauss-Newton standard error.

Run:  python examples/calibrate_ball.py     (writes examples/output/calibrate_ball.png)
"""

import os


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _calibration import figure, noisy, observe, report  # noqa: E402
from _references_mechanics import ball_state, output_path  # noqa: E402

import nivpjax as nj  # noqa: E402


jax.config.update("jax_enable_x64", True)

TRUTH = {"e": 0.8}
TIMES = np.linspace(0.05, 3.0, 40)
SIGMA = 0.01
scene, x0, args = nj.scenes.bouncing_ball(height=1.0)


def heights(params, times):
    return observe(scene, 3.0, x0, dict(args, e=params["e"]), times, h_max=0.02)[:, 0]


def residuals(params, data):
    return heights(params, jnp.asarray(TIMES)) - data


def main():
    exact = ball_state(TIMES, 1.0, 0.0, TRUTH["e"], 9.81)[0]
    data = jnp.asarray(noisy(exact, SIGMA))
    start = {"e": jnp.asarray(0.5)}
    run = jax.jit(lambda p, d: nj.fit(residuals, p, d), compiler_options=nj.compiler_options())
    t0 = time.perf_counter()
    fit = jax.block_until_ready(run(start, data))
    print(f"compile + fit: {time.perf_counter() - t0:.1f} s")
    worst = report(["e"], TRUTH, start, fit)
    grid = np.linspace(0.0, 3.0, 400)
    fitted = np.asarray(jax.jit(heights)(fit.params, jnp.asarray(grid[1:])))
    figure(
        output_path("calibrate_ball.png"),
        f"restitution e = {float(fit.params['e']):.4f} +- {float(fit.stderr['e']):.4f}",
        TIMES,
        data,
        grid[1:],
        {"fit": fitted, "truth": ball_state(grid[1:], 1.0, 0.0, TRUTH["e"], 9.81)[0]},
        {"start e = 0.5": fit.history},
        "height q",
    )
    return worst


if __name__ == "__main__":
    assert main() < 0.02
