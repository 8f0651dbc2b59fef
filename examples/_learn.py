"""Shared driver of the `learn_*.py` examples: train one scene's step-size policy with
antithetic ES (a few minutes on 2 CPU cores), save it into the package, and compare it with
PID on held-out draws."""

import argparse
import os
import time


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402


jax.config.update("jax_enable_x64", True)

import jax.random as jr  # noqa: E402
import numpy as np  # noqa: E402

import nivpjax as nj  # noqa: E402
from nivpjax.learn import draw, evaluate, pretrained  # noqa: E402


def main(name, iterations=10, batch=8):
    parser = argparse.ArgumentParser()
    parser.add_argument("--iterations", type=int, default=iterations)
    parser.add_argument("--batch", type=int, default=batch)
    parser.add_argument("--no-save", action="store_true")
    opts = parser.parse_args()
    os.makedirs("examples/output", exist_ok=True)
    start = time.perf_counter()
    result = pretrained.train_scene(
        name,
        iterations=opts.iterations,
        batch=opts.batch,
        save=not opts.no_save,
        curve_png=f"examples/output/learn_{name}.png",
    )
    print(f"{name}: trained in {time.perf_counter() - start:.0f} s (compile included)")
    curve = ", ".join(f"{h['objective']:.0f}" for h in result.history)
    print(f"objective per iteration: {curve}")
    task = nj.learn.tasks.TASKS[name]()
    x0, args, y_ref, _ = draw(task, jr.PRNGKey(1234), 8)
    pid = evaluate(task, nj.PIDController(rtol=task.rtol, atol=task.atol), x0, args, y_ref)
    pol = evaluate(task, task.policy_controller(result.policy), x0, args, y_ref)
    for label, m in (("PID", pid), ("policy", pol)):
        print(
            f"held-out {label:>6}: attempts {np.mean(m.attempts):7.1f}  rejected "
            f"{np.mean(m.rejections):6.1f}  Newton {np.mean(m.iterations):8.1f}  error "
            f"{np.exp(np.mean(np.log(np.maximum(m.error, 1e-12)))):9.3g}  failures "
            f"{int(np.sum(m.failed))}"
        )
