"""Fixed-step Bathe on the bouncing ball: the cost of a step alone and per step-trajectory
in a vmapped batch (issue 11's targets: at most 8 µs and 1.5 µs).

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.fixed_step [--batch 1000] [--steps 400]

Bathe + semismooth Newton with `ConstantStepSize` (h = t1 / steps), the default ball
(e = 0.8, H = 1) to t1 = 3 (six impacts), compiled once per shape; minimum over repeats
of the wall time divided by the steps taken (times the batch size for the batch).
"""

import argparse

import jax
import jax.numpy as jnp

import nivpjax as nj

from ._common import time_once


def _make(steps, t1):
    scene, x0, args = nj.scenes.bouncing_ball()
    h0 = t1 / steps

    def run(e):
        return scene.solve(
            0.0,
            t1,
            x0,
            dict(args, e=e),
            stepper=nj.Bathe(),
            controller=nj.ConstantStepSize(),
            h0=h0,
            max_steps=steps + 1,
            throw=False,
        )

    return run, args["e"]


def _best(fn, arg, repeats):
    # The minimum of `repeats` calls after a warm-up call, and the last output.
    runs = [time_once(fn, arg) for _ in range(repeats + 1)][1:]
    return min(seconds for seconds, _ in runs), runs[-1][1]


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks.fixed_step")
    parser.add_argument("--batch", type=int, default=1000)
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=7)
    a = parser.parse_args(argv)
    t1 = 3.0
    run, e = _make(a.steps, t1)
    options = nj.compiler_options()  # as nivpjax's own top-level programs
    single = jax.jit(run, compiler_options=options)
    seconds, sol = _best(single, jnp.asarray(e), a.repeats)
    n = int(sol.n_accepted) + int(sol.n_rejected)
    assert sol.result == nj.RESULTS.successful, nj.RESULTS[sol.result]
    print(f"alone: {n} steps, {seconds * 1e3:.2f} ms, {seconds / n * 1e6:.2f} µs per step")
    batched = jax.jit(jax.vmap(run), compiler_options=options)
    es = jnp.linspace(0.7, 0.9, a.batch)
    seconds, sol = _best(batched, es, max(2, a.repeats // 2))
    total = int(jnp.sum(sol.n_accepted + sol.n_rejected))
    print(
        f"vmap of {a.batch}: {total} step-trajectories, {seconds:.3f} s, "
        f"{seconds / total * 1e6:.2f} µs per step-trajectory"
    )


if __name__ == "__main__":
    main()
