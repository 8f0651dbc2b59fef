"""The cost of `t_eval` output against the solve's (issue 31: below 10% for 1000 output
times on the benchmark scenes).

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.teval_cost [--out FILE] [--repeats 9]

Per scene, for Bathe and the trapezoidal rule at rtol 1e-6 (atol 1e-8): the same solve as
a user calls it (`Scene.solve` / `nj.solve`, concrete arguments, every step saved) without
`t_eval` and with 1000 output times spread over [t0, t1]. Run times are medians of
`--repeats` calls after the first (compiled) one, the two variants called alternately so
that a change in the machine's load falls on both; the ratio is the extra cost over the
solve's, (with - without) / without, both from the same run. Compile times are the first
call's wall time (tracing and XLA compilation, no persistent cache), apart.

The interpolation alone (`nivpjax._loop.interpolate` and `interpolate_multipliers` jitted
apart on the solution, as `nj.solve` calls them after the loop) is timed as well: on a
loaded machine the difference of two end-to-end medians is noisy, this column is not.
"""

import argparse
import functools
import statistics

import jax
import jax.numpy as jnp
import numpy as np

import nivpjax as nj
from nivpjax._loop import interpolate, interpolate_multipliers
from nivpjax._model import Model
from nivpjax._validate import check_mass_matrix

from ._common import time_once  # (and float64)
from .sweeping_teval import PROJECTOR, T1, vector_field


N_OUT = 1000
RTOL, ATOL = 1e-6, 1e-8
STEPPERS = {"Bathe": nj.Bathe, "Trapezoidal": nj.Trapezoidal}


def _scene_case(scene, x0, args, t1):
    # The model `Scene.solve` builds (its effects resolved at the initial state).
    resolved = scene.resolved(0.0, jnp.asarray(x0), args)
    y0 = resolved.initial_state(jnp.asarray(x0), None)
    mass, algebraic = check_mass_matrix(resolved.full_mass_matrix, y0.shape[0], jnp.float64)
    model = Model.build(
        resolved.vector_field,
        resolved.projector,
        mass,
        algebraic,
        equation_rows=resolved.equation_rows,
    )

    def run(stepper, t_eval):
        return scene.solve(
            0.0,
            t1,
            x0,
            args,
            stepper=stepper,
            controller=nj.PIDController(rtol=RTOL, atol=ATOL),
            t_eval=t_eval,
        )

    return run, model, args, t1


def _sweeping_case():
    mass, algebraic = check_mass_matrix(None, 1, jnp.float64)
    model = Model.build(vector_field, PROJECTOR, mass, algebraic)

    def run(stepper, t_eval):
        return nj.solve(
            vector_field,
            0.0,
            T1,
            jnp.zeros(1),
            projector=PROJECTOR,
            stepper=stepper,
            controller=nj.PIDController(rtol=RTOL, atol=ATOL),
            t_eval=t_eval,
        )

    return run, model, None, T1


def cases():
    """`{label: (run(stepper, t_eval), model, args, t1)}` of the benchmark scenes."""
    return {
        "bouncing ball": _scene_case(*nj.scenes.bouncing_ball(), 3.0),
        "block on a plane, friction cone": _scene_case(*nj.scenes.block_on_plane(cone=True), 1.0),
        "relay, leaving its surface": _scene_case(*nj.scenes.relay(amplitude=1.3), 3.0),
        "spring slider, driven stick-slip": _scene_case(
            *nj.scenes.spring_slider(drive_velocity=0.5), 10.0
        ),
        "sweeping process": _sweeping_case(),
        "ball in a bowl": _scene_case(*nj.scenes.ball_in_bowl(), 3.0),
    }


def measure(label, run, model, args, t1, stepper_name, repeats):
    stepper = STEPPERS[stepper_name]()
    t_eval = jnp.linspace(0.0, t1, N_OUT)
    plain = functools.partial(run, stepper, None)
    with_out = functools.partial(run, stepper, t_eval)
    c_plain, sol = time_once(plain)
    c_out, _ = time_once(with_out)
    a, b = [], []
    for _ in range(repeats):
        a.append(time_once(plain)[0])
        b.append(time_once(with_out)[0])
    t_plain, t_out = statistics.median(a), statistics.median(b)
    # The interpolation alone, on the saved steps of the plain solve.

    def outputs(sol, t_eval, args):
        y = interpolate(sol, t_eval, model, args, stepper)
        return y, interpolate_multipliers(sol, t_eval, y, model, args)

    inter = jax.jit(outputs)
    c_inter, _ = time_once(lambda: inter(sol, t_eval, args))
    t_inter = statistics.median(
        time_once(lambda: inter(sol, t_eval, args))[0] for _ in range(repeats)
    )
    return dict(
        scene=label,
        stepper=stepper_name,
        steps=int(sol.n_accepted),
        solve=t_plain,
        with_out=t_out,
        ratio=(t_out - t_plain) / t_plain,
        ratio_min=(min(b) - min(a)) / min(a),
        inter=t_inter,
        inter_ratio=t_inter / t_plain,
        compile_solve=c_plain,
        compile_out=c_out,
        compile_inter=c_inter,
    )


def table(rows):
    lines = [
        "| scene | stepper | steps | solve | solve with 1000 `t_eval` | extra / solve "
        "| (of the fastest runs) | interpolation alone | alone / solve | compile: solve "
        "| compile: with `t_eval` |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['stepper']} | {r['steps']} | {r['solve'] * 1e3:.2f} ms "
            f"| {r['with_out'] * 1e3:.2f} ms | {100 * r['ratio']:.1f}% "
            f"| {100 * r['ratio_min']:.1f}% "
            f"| {r['inter'] * 1e3:.3f} ms | {100 * r['inter_ratio']:.1f}% "
            f"| {r['compile_solve']:.1f} s | {r['compile_out']:.1f} s |"
        )
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks.teval_cost")
    parser.add_argument("--out", default=None, help="write the markdown table here")
    parser.add_argument("--repeats", type=int, default=9)
    only = "scenes whose label holds one of these, comma-separated"
    parser.add_argument("--only", default=None, help=only)
    a = parser.parse_args(argv)
    rows = []
    for label, (run, model, args, t1) in cases().items():
        if a.only and not any(word in label for word in a.only.split(",")):
            continue
        for name in STEPPERS:
            row = measure(label, run, model, args, t1, name, a.repeats)
            print(row, flush=True)
            rows.append(row)
    text = "\n".join(table(rows))
    print(text)
    if a.out:
        with open(a.out, "w") as fh:
            fh.write(text + "\n")
    return rows


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
