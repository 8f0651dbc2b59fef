"""A ball in a bowl (issue 33): nivpjax against the reference `solve_nivp.solve_ivp_ns` at
equal error.

The pendulum held by a circular wall (R = 1, g = 9.81, from the bottom at speed 1, T = 2,
about 18 degrees, never leaving the wall), y = [v1, v2, q1, q2] for the reference with its
unilateral projection (GeneralMoreau: the gap 1 - |q|, the normal velocity -q.v/|q|, its
Jacobian and the impulse along the normal), the trapezoidal rule with the VI solver at
tol 1e-10 and the controller options of its bouncing-ball notebook (h_down 0.5, h_up 1.5,
method_order 1, use_PI False), atol = rtol / 100. nivpjax: `nj.scenes.ball_in_bowl()`
(`Contact(curved=True)`), Bathe and the trapezoidal rule with the default PID controller,
one compiled program for every rtol (the tolerances are arguments).

Error: the largest position error over the accepted steps against the event-driven
reference `bowl_state` (`examples/_references_mechanics.py`). Timings: nivpjax the median
of 5 runs of the compiled call; the reference one run (they take seconds). The ratio at
each reference point is its time over the fastest nivpjax run with an error at most as
large. Target: at least 30x.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.bowl_reference

Writes benchmarks/results/bowl_reference.md.
"""

import contextlib
import io
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import solve_nivp

import nivpjax as nj


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
from _references_mechanics import bowl_state  # noqa: E402


jax.config.update("jax_enable_x64", True)
G, T = 9.81, 2.0
OUT = Path(__file__).resolve().parent / "results" / "bowl_reference.md"


def _norm(q):
    return np.sqrt(q @ q)


def reference_kwargs(rtol):
    def normal(y):
        return -y[2:] / _norm(y[2:])  # dg/dq, acting on the velocities y[:2]

    popts = dict(
        gap=lambda t, y: np.array([1.0 - _norm(y[2:])]),
        u_map=lambda t, y: np.array([normal(y) @ y[:2]]),
        J_u=lambda t, y: np.array([[*normal(y), 0.0, 0.0]]),
        G_apply=lambda t, y, lam: np.array([*(normal(y) * lam[0]), 0.0, 0.0]),
        e=0.0,
        gap_tol=0.0,
        lcp_maxit=200,
        lcp_tol=1e-10,
        tc_tol=1e-10,
    )
    return dict(
        fun=lambda t, y: np.array([0.0, -G, y[0], y[1]]),
        t_span=(0.0, T),
        y0=np.array([1.0, 0.0, 0.0, -1.0]),
        method="trapezoidal",
        projection="unilateral",
        solver="VI",
        projection_opts=popts,
        solver_opts=dict(tol=1e-10, max_iter=200),
        adaptive_opts=dict(
            h0=1e-3, h_min=1e-12, h_down=0.5, h_up=1.5, method_order=1, use_PI=False
        ),
        atol=rtol / 100,
        rtol=rtol,
        h0=1e-3,
        component_slices=[slice(i, i + 1) for i in range(4)],
    )


def position_error(ts, q):
    return float(np.max(np.abs(q - bowl_state(ts, 1.0, G)[:, :2])))


def run_reference(rtol):
    start = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        t, y, *_ = solve_nivp.solve_ivp_ns(**reference_kwargs(rtol))
    elapsed = time.perf_counter() - start
    t, y = np.asarray(t), np.asarray(y)
    y = y if y.shape[0] == len(t) else y.T
    return position_error(t, y[:, 2:4]), len(t) - 1, elapsed


def nivpjax_runner(stepper):
    scene, x0, args = nj.scenes.ball_in_bowl()

    @jax.jit
    def run(rtol):
        controller = nj.PIDController(rtol=rtol, atol=rtol / 100)
        return scene.solve(
            0.0, T, x0, args, stepper=stepper, controller=controller, max_steps=20000
        )

    return run


def run_nivpjax(run, rtol):
    sol = jax.block_until_ready(run(jnp.asarray(rtol)))
    times = []
    for _ in range(5):
        start = time.perf_counter()
        jax.block_until_ready(run(jnp.asarray(rtol)))
        times.append(time.perf_counter() - start)
    k = int(sol.n_accepted)
    ts, q = np.asarray(sol.ts[: k + 1]), np.asarray(sol.ys[: k + 1, :2])
    assert sol.result == nj.RESULTS.successful
    return position_error(ts, q), k, float(np.median(times))


def main():
    rows, ours = [], []
    for name, stepper in (("Bathe", nj.Bathe()), ("Trapezoidal", nj.Trapezoidal())):
        run = nivpjax_runner(stepper)
        for rtol in (1e-3, 1e-4, 1e-5, 1e-6, 1e-7):
            err, steps, seconds = run_nivpjax(run, rtol)
            ours.append((err, seconds))
            rows.append(
                f"| nivpjax {name} | {rtol:.0e} | {steps} | {err:.2e} | {seconds * 1e3:.2f} ms | |"
            )
    for rtol in (1e-3, 1e-4, 1e-5):
        err, steps, seconds = run_reference(rtol)
        match = [s for e, s in ours if e <= err]
        ratio = f"{seconds / min(match):.0f}x" if match else "no nivpjax run as accurate"
        cells = f"{rtol:.0e} | {steps} | {err:.2e} | {seconds:.2f} s | {ratio}"
        rows.append(f"| solve_nivp trapezoidal + VI | {cells} |")
    table = "\n".join(
        [
            "| code | rtol | steps | position error | time | reference / nivpjax at equal error |",
            "|---|---|---|---|---|---|",
            *rows,
        ]
    )
    about = __doc__.split("\n\n")[1]
    text = f"# A ball in a bowl against the reference package\n\n{about}\n\n{table}\n"
    OUT.write_text(text)
    print(table)


if __name__ == "__main__":
    main()
