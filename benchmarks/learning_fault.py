"""The companion study's fault experiment: learned step sizes against the study's
step-doubling baseline and nivpjax's PID, at matched accuracy of the mean final slip.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.learning --fault [--sizes 10 20] [--draws 4]
        [--iterations 8] [--sac]

On held-out draws of (Dc, delta-mu, initial over-stress) (`nivpjax.learn.fault_task`, the
study's kernel files, Bathe with the VI solver as the study): the study's baseline
(`nj.StepDoublingController`, h0 = 5e-3, steps in [1e-7, 1e3], the study's rtol 1e-3 and a
sweep), PID at a sweep of tolerances, and a learned `PolicyController` (ES through
`nivpjax.learn.train`, trained on other draws at the same size; the policy starts as PID's
integral rule). Accuracy: the relative error of the mean final slip against PID at rtol
1e-7. Counts are means over the draws; wall time per draw (second call, compile
excluded). `--sac` (needs `nivpjax[rl]`) adds the study's own kind of agent: rejax SAC on
`FaultEnv` (2 x 2 cells), rolled out at each size.
Writes benchmarks/results/learning_fault.md and .json.
"""

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402


jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import jax.random as jr  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402

import nivpjax as nj  # noqa: E402
from nivpjax import learn  # noqa: E402
from nivpjax.learn import fault  # noqa: E402


DATA = Path("/work/shared/fault")
KERNELS = {
    2: ("kijs_2x2elem-3x3length.npy", 3.0, 3.0),
    10: ("kijs_10x10elem-3x3length.npy", 3.0, 3.0),
    20: ("kijs_20x20elem-5x4length.npy", 5.0, 4.0),
}
OUT = Path(__file__).parent / "results" / "learning_fault"


def task_for(size, max_steps=4000):
    name, length, depth = KERNELS[size]
    path = Path(os.environ.get("NIVPJAX_FAULT_DATA", DATA)) / name
    return fault.fault_task(
        path, length=length, depth=depth, max_steps=max_steps, reference_max_steps=100_000
    )


@eqx.filter_jit
def _solve(task, controller, x0, args, h0):
    sol = task.solve(controller, x0, args, h0=h0, saveat=nj.SaveAt())
    return (
        sol.n_accepted,
        sol.n_rejected,
        sol.n_iterations,
        sol.result == nj.RESULTS.successful,
        fault.mean_final_slip(task, sol.y_final),
    )


def run(task, controller, x0, args, slip_ref, h0=None):
    """Per draw: solve twice (the second timed); means of the counts and the errors."""
    rows = []
    for i in range(x0.shape[0]):
        xi, ai = x0[i], jax.tree.map(lambda a: a[i], args)
        h = None if h0 is None else jnp.asarray(h0)
        jax.block_until_ready(_solve(task, controller, xi, ai, h))
        start = time.perf_counter()
        acc, rej, its, ok, slip = jax.block_until_ready(_solve(task, controller, xi, ai, h))
        seconds = time.perf_counter() - start
        err = abs(float(slip) / float(slip_ref[i]) - 1.0) if ok else float("nan")
        rows.append((int(acc), int(rej), int(its), bool(ok), err, seconds))
    a = np.array(rows, dtype=float)
    ok = a[:, 3] > 0
    errs = a[ok, 4]
    return dict(
        accepted=float(a[:, 0].mean()),
        rejected=float(a[:, 1].mean()),
        iterations=float(a[:, 2].mean()),
        failures=int((~ok).sum()),
        error=float(errs.max()) if errs.size else float("nan"),
        error_mean=float(errs.mean()) if errs.size else float("nan"),
        seconds=float(a[:, 5].mean()),
    )


def reference(task, x0, args):
    pid = nj.PIDController(rtol=1e-7, atol=1e-9)
    slips = []
    for i in range(x0.shape[0]):
        ai = jax.tree.map(lambda a: a[i], args)
        t = dataclasses.replace(task, max_steps=100_000)
        *_, ok, slip = _solve(t, pid, x0[i], ai, None)
        if not bool(ok):
            raise RuntimeError(f"the reference of draw {i} failed")
        slips.append(float(slip))
    return np.array(slips)


def train_es(task, iterations, seed=1):
    policy = learn.make_policy(
        task.full_stepper.error_order, key=jr.PRNGKey(seed), width=8, depth=1
    )
    objective = learn.Objective(attempts=1.0, iterations=0.02, rejections=1.0, error=20.0)
    start = time.perf_counter()
    result = learn.train(
        task,
        policy,
        objective=objective,
        optimiser=optax.adam(0.05),
        iterations=iterations,
        batch=4,
        pairs=4,
        sigma=0.1,
        seed=seed,
    )
    return result, time.perf_counter() - start


def size_rows(size, n_draws, iterations):
    task = task_for(size)
    x0, args = jax.vmap(task.sample)(jr.split(jr.PRNGKey(2024), n_draws))
    t = time.perf_counter()
    slip_ref = reference(task, x0, args)
    ref_seconds = time.perf_counter() - t
    rows = []
    for rtol in (1e-2, 1e-3, 1e-4):
        c = nj.StepDoublingController(
            rtol=jnp.asarray(rtol), atol=jnp.asarray(1e-6), h_min=1e-7, h_max=1e3
        )
        rows.append(
            dict(
                controller="step doubling (study)",
                rtol=rtol,
                **run(task, c, x0, args, slip_ref, 5e-3),
            )
        )
        print(rows[-1], flush=True)
    for rtol in (1e-2, 1e-3, 1e-4, 1e-5):
        c = nj.PIDController(rtol=jnp.asarray(rtol), atol=jnp.asarray(rtol * 1e-3))
        rows.append(dict(controller="PID", rtol=rtol, **run(task, c, x0, args, slip_ref)))
        print(rows[-1], flush=True)
    log = {}
    if iterations > 0:
        result, seconds = train_es(task, iterations)
        log = dict(seconds=seconds, history=[h["objective"] for h in result.history], size=size)
        c = task.policy_controller(result.policy)
        rows.append(
            dict(controller="ES policy", rtol=task.rtol, **run(task, c, x0, args, slip_ref))
        )
        print(rows[-1], flush=True)
    return dict(
        size=size,
        draws=n_draws,
        rows=rows,
        es=log,
        reference_seconds=ref_seconds,
        slip_ref=slip_ref.tolist(),
    )


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks.learning --fault")
    parser.add_argument("--sizes", nargs="+", type=int, default=[10])
    parser.add_argument("--draws", type=int, default=4)
    parser.add_argument("--iterations", type=int, default=8)
    opts = parser.parse_args(argv)
    OUT.parent.mkdir(exist_ok=True)
    for size in opts.sizes:
        t = time.perf_counter()
        result = size_rows(size, opts.draws, opts.iterations)
        result["seconds"] = time.perf_counter() - t
        result["load"] = os.getloadavg()[0]
        Path(f"{OUT}_{size}.json").write_text(json.dumps(result, indent=1))
        print(f"{size} x {size}: done in {result['seconds']:.0f} s", flush=True)


if __name__ == "__main__":
    main()
