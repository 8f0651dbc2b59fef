"""Output between steps on Moreau's sweeping process (issue 31): errors at the accepted steps
and at `t_eval` against the exact solution, and the cost of `t_eval`.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.sweeping_teval [--out FILE]

The problem: z' in -u'(t) - N_[-1,1](z), u(t) = 1.5 sin(1.3 t), z(0) = 0, T = 10, written with
`nj.solve` and a `Box` on a differential row, the default PID controller with
atol = rtol / 100, 2001 output times. Its exact solution is the play operator of u
(`play_exact`). The ratio column is the worst, over output times, of the `t_eval` error to
the larger error of the two accepted steps around it (issue 31's target: at most 2).

The cost: the interpolation at 1000 output times against the solve, on benchmark scenes
(`cost_table`; minimum of repeats after a warm-up).
"""

import argparse
import functools

import jax
import jax.numpy as jnp
import numpy as np

import nivpjax as nj
from nivpjax._loop import interpolate, interpolate_multipliers
from nivpjax._model import Model
from nivpjax._validate import check_mass_matrix

from ._common import time_once


AMPLITUDE, OMEGA, T1 = 1.5, 1.3, 10.0


def u_of(t, amplitude=AMPLITUDE, omega=OMEGA):
    return amplitude * np.sin(omega * np.asarray(t, float))


def play_exact(t, amplitude=AMPLITUDE, omega=OMEGA):
    """z(t) of the sweeping process z' in -u' - N_[-1,1](z), u = amplitude sin(omega t),
    z(0) = 0, from the play operator x = z + u of width 1: on each monotone piece of u
    starting at t_k, x = max(x(t_k), u - 1) where u increases and min(x(t_k), u + 1) where
    it decreases; x(0) = 0."""
    t = np.asarray(t, float)
    # Extrema of u: omega t = pi/2 + k pi.
    k_max = int(np.ceil(omega * max(float(t.max()), 0.0) / np.pi)) + 1
    breaks = np.concatenate([[0.0], (np.pi / 2 + np.pi * np.arange(k_max)) / omega])
    x_at = [0.0]
    for k in range(len(breaks) - 1):
        up = k % 2 == 0
        u_end = u_of(breaks[k + 1], amplitude, omega)
        x_at.append(max(x_at[-1], u_end - 1) if up else min(x_at[-1], u_end + 1))
    piece = np.clip(np.searchsorted(breaks, t, side="right") - 1, 0, len(breaks) - 2)
    xk = np.asarray(x_at)[piece]
    u = u_of(t, amplitude, omega)
    x = np.where(piece % 2 == 0, np.maximum(xk, u - 1), np.minimum(xk, u + 1))
    return x - u


def vector_field(t, y, args):
    return -AMPLITUDE * OMEGA * jnp.cos(OMEGA * t) * jnp.ones_like(y)


PROJECTOR = nj.BlockProjector([([0], nj.Box(-1.0, 1.0))])
STEPPERS = {
    "BackwardEuler": nj.BackwardEuler,
    "Trapezoidal": nj.Trapezoidal,
    "Bathe": nj.Bathe,
    "EmbeddedBETR": nj.EmbeddedBETR,
}
TABLE = [
    ("Bathe", 1e-3),
    ("Bathe", 1e-5),
    ("Bathe", 1e-7),
    ("Trapezoidal", 1e-5),
    ("Trapezoidal", 1e-7),
    ("BackwardEuler", 1e-5),
    ("EmbeddedBETR", 1e-5),
]


def sweeping_solve(stepper, rtol, t_eval, dtype=jnp.float64, max_steps=20000):
    """The sweeping process solved with `stepper` at `rtol` (atol = rtol / 100)."""
    return nj.solve(
        vector_field,
        0.0,
        T1,
        jnp.zeros(1, dtype),
        projector=PROJECTOR,
        stepper=stepper,
        controller=nj.PIDController(rtol=rtol, atol=rtol / 100),
        t_eval=None if t_eval is None else jnp.asarray(t_eval, dtype),
        max_steps=max_steps,
    )


def errors(sol):
    """`(steps, error at steps, error at t_eval, worst ratio)`: the last is the largest
    `t_eval` error over the larger error of the two accepted steps around it."""
    k = int(sol.n_accepted)
    ts, ys = np.asarray(sol.ts[: k + 1]), np.asarray(sol.ys[: k + 1, 0])
    step_err = np.abs(ys - play_exact(ts))
    t_eval = np.asarray(sol.t_eval)
    eval_err = np.abs(np.asarray(sol.y_eval[:, 0]) - play_exact(t_eval))
    i = np.clip(np.searchsorted(ts, t_eval, side="right") - 1, 0, k - 1)
    around = np.maximum(step_err[i], step_err[i + 1])
    ratio = np.max(eval_err / np.maximum(around, 1e-15))
    return k, step_err.max(), eval_err.max(), ratio


def accuracy_table():
    t_eval = np.linspace(0.0, T1, 2001)
    lines = [
        "| stepper | rtol | steps | error at steps | error at `t_eval` | worst ratio |",
        "|---|---|---|---|---|---|",
    ]
    for name, rtol in TABLE:
        sol = sweeping_solve(STEPPERS[name](), rtol, t_eval)
        k, e_step, e_eval, ratio = errors(sol)
        lines.append(f"| {name} | {rtol:.0e} | {k} | {e_step:.1e} | {e_eval:.1e} | {ratio:.1f} |")
    return lines


def _best(fn, args, repeats):
    runs = [time_once(fn, *args) for _ in range(repeats + 1)][1:]
    return min(seconds for seconds, _ in runs)


def _model(vector_field, projector, mass_matrix, equation_rows, n):
    # The model `nj.solve` builds from these arguments.
    mass, algebraic = check_mass_matrix(mass_matrix, n, jnp.float64)
    return Model.build(vector_field, projector, mass, algebraic, equation_rows=equation_rows)


def _interpolate(model, sol, t_eval, args):
    # What `t_eval` adds to a solve: the states and the multipliers there.
    y_eval = interpolate(sol, t_eval, model, args)
    return y_eval, interpolate_multipliers(sol, t_eval, y_eval, model, args)


def cost_table(repeats):
    """The solve (as a user calls it: concrete arguments, nivpjax's own compiled program)
    against the interpolation at 1000 output times of its solution (`interpolate` and
    `interpolate_multipliers`, jitted alone: the whole cost `t_eval` adds; timing the
    solve with and without `t_eval` reads the load of a shared machine instead), per
    scene, Bathe at rtol 1e-6."""
    controller = nj.PIDController(rtol=1e-6, atol=1e-8)
    cases = {}
    for label, (scene, x0, args), t1 in [
        ("bouncing ball", nj.scenes.bouncing_ball(), 3.0),
        ("spring slider, driven", nj.scenes.spring_slider(drive_velocity=0.5), 10.0),
        ("relay", nj.scenes.relay(), 10.0),
    ]:
        y0 = scene.initial_state(jnp.asarray(x0), None)
        model = _model(
            scene.vector_field,
            scene.projector,
            scene.full_mass_matrix,
            scene.equation_rows,
            y0.shape[0],
        )
        run = functools.partial(scene.solve, 0.0, t1, x0, controller=controller)
        cases[label] = (run, args, model, t1)
    sweeping = _model(vector_field, PROJECTOR, None, None, 1)
    run = lambda args: sweeping_solve(nj.Bathe(), 1e-6, None)  # noqa: E731
    cases["sweeping process"] = (run, None, sweeping, T1)
    lines = [
        "| scene | steps | solve | states and multipliers at 1000 `t_eval` | ratio |",
        "|---|---|---|---|---|",
    ]
    for label, (run, args, model, t1) in cases.items():
        t_eval = jnp.linspace(0.0, t1, 1000)
        t_solve = _best(run, (args,), repeats)
        sol = run(args)
        inter = jax.jit(functools.partial(_interpolate, model))
        t_inter = _best(inter, (sol, t_eval, args), repeats)
        lines.append(
            f"| {label} (t1 = {t1:g}) | {int(sol.n_accepted)} | {t_solve * 1e3:.2f} ms "
            f"| {t_inter * 1e3:.3f} ms | {100 * t_inter / t_solve:.1f}% |"
        )
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks.sweeping_teval")
    parser.add_argument("--out", default=None, help="write the markdown tables here")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-cost", action="store_true")
    a = parser.parse_args(argv)
    lines = ["## Sweeping process: error at the steps and at 2001 `t_eval` points", ""]
    lines += accuracy_table()
    if not a.no_cost:
        lines += ["", "## Cost of 1000 `t_eval` points (Bathe, rtol 1e-6, atol 1e-8)", ""]
        lines += cost_table(a.repeats)
    text = "\n".join(lines)
    print(text)
    if a.out:
        with open(a.out, "w") as fh:
            fh.write(text + "\n")


if __name__ == "__main__":
    main()
