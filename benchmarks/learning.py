"""Learned step-size control against PID at matched error, on held-out parameter draws.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.learning [--scenes ...] [--draws 16]
    OPENBLAS_NUM_THREADS=1 python -m benchmarks.learning --fault [...]

`--fault` runs the companion study's fault experiment instead (`benchmarks/learning_fault.py`,
its own options).

Uses the policies shipped in `nivpjax/learn/policies/` (trained by `examples/learn_*.py`).
For each scene: PID at six tolerances (a sweep around the task's rtol) and the policy at
the task's rtol, all on the same held-out draws; error is the RMS scaled error against a
tight reference at 20 output times (scaled by the task's atol + rtol|y|). "PID at matched
error" interpolates PID's Newton iterations log-log at the policy's error. Wall time is
per draw, of one vmapped batch (second call, compile excluded). Writes
benchmarks/results/learning.md.
"""

import argparse
import json
import os
import sys
import time
from pathlib import Path


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402


jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import jax.random as jr  # noqa: E402
import numpy as np  # noqa: E402

import nivpjax as nj  # noqa: E402
from nivpjax.learn import draw, evaluate, pretrained  # noqa: E402
from nivpjax.learn.tasks import TASKS  # noqa: E402


FACTORS = (10.0, 3.0, 1.0, 0.3, 0.1, 0.03)
OUT = Path(__file__).parent / "results" / "learning.md"


def _gmean(x):
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.exp(np.mean(np.log(np.maximum(x, 1e-12))))) if x.size else float("inf")


def _summary(m, seconds, n):
    ok = ~np.asarray(m.failed)
    return dict(
        attempts=float(np.mean(m.attempts)),
        rejected=float(np.mean(m.rejections)),
        newton=float(np.mean(m.iterations)),
        error=_gmean(np.asarray(m.error)[ok]),
        failures=int(np.sum(~ok)),
        ms=1e3 * seconds / n,
    )


def _timed(fn, *args):
    jax.block_until_ready(fn(*args))
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - start


def _matched(pid_rows, error):
    rows = sorted((r for r in pid_rows if r["failures"] == 0), key=lambda r: r["error"])
    errs = np.log([r["error"] for r in rows])
    work = np.log([r["newton"] for r in rows])
    if not rows or not errs[0] <= np.log(error) <= errs[-1]:
        return None
    return float(np.exp(np.interp(np.log(error), errs, work)))


def scene(name, n_draws):
    task, policy = pretrained.load(name)
    x0, args, y_ref, ok = draw(task, jr.PRNGKey(2024), n_draws)
    pid_rows = []
    for f in FACTORS:
        rtol = task.rtol * f
        c = nj.PIDController(rtol=jnp.asarray(rtol), atol=jnp.asarray(task.atol * f))
        m, s = _timed(lambda c=c: evaluate(task, c, x0, args, y_ref))
        pid_rows.append(dict(rtol=rtol, **_summary(m, s, n_draws)))
    m, s = _timed(lambda: evaluate(task, task.policy_controller(policy), x0, args, y_ref))
    pol = dict(rtol=task.rtol, **_summary(m, s, n_draws))
    log_path = pretrained.POLICY_DIR / f"{name}.json"
    log = json.loads(log_path.read_text()) if log_path.exists() else {}
    return dict(name=name, pid=pid_rows, policy=pol, refs_ok=int(np.sum(ok)), log=log)


def _row(label, r):
    return (
        f"| {label} | {r['rtol']:.0e} | {r['attempts']:.1f} | {r['rejected']:.1f} | "
        f"{r['newton']:.0f} | {r['error']:.3g} | {r['failures']} | {r['ms']:.2f} |"
    )


def report(results, n_draws, seconds):
    lines = [
        "# Learned step-size control vs PID (held-out draws)",
        "",
        f"`python -m benchmarks.learning --draws {n_draws}`; {time.strftime('%Y-%m-%d %H:%M')}, "
        f"{os.cpu_count()} CPUs (load average at the end of each scene below: above 1, other "
        "work ran beside it and wall times are inflated). Means over the held-out draws; "
        "error: geometric mean of the RMS scaled error vs the tight reference.",
        "",
    ]
    for r in results:
        pol = r["policy"]
        matched = _matched(r["pid"], pol["error"])
        ratio = f"{matched / pol['newton']:.2f}x" if matched else "n/a (outside the PID sweep)"
        log = r["log"]
        curve = ", ".join(f"{h['objective']:.0f}" for h in log.get("history", []))
        lines += [
            f"## {r['name']}",
            "",
            f"PID Newton iterations at the policy's error / policy's: **{ratio}**. "
            f"References ok: {r['refs_ok']}/{n_draws}. Training (`learn.train` wall time, "
            "the ES step's compilation included): "
            f"{log.get('seconds', float('nan')):.0f} s, objective per iteration: {curve}. "
            f"Benchmark: {r.get('seconds', 0):.0f} s, load average {r.get('load', 0):.1f}.",
            "",
            "| controller | rtol | attempts | rejected | Newton | error | failures | ms/draw |",
            "|---|---|---|---|---|---|---|---|",
            *[_row("PID", p) for p in r["pid"]],
            _row("policy", pol),
            "",
        ]
    return "\n".join(lines)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if "--fault" in argv:
        from benchmarks import learning_fault

        return learning_fault.main([a for a in argv if a != "--fault"])
    parser = argparse.ArgumentParser(prog="python -m benchmarks.learning")
    parser.add_argument("--scenes", nargs="+", choices=list(TASKS), default=list(TASKS))
    parser.add_argument("--draws", type=int, default=16)
    opts = parser.parse_args(argv)
    start = time.perf_counter()
    for name in opts.scenes:
        if not (pretrained.POLICY_DIR / f"{name}.eqx").exists():
            print(f"{name}: no shipped policy, skipped (run examples/learn_{name}.py)")
            continue
        t = time.perf_counter()
        result = scene(name, opts.draws)
        result["seconds"] = time.perf_counter() - t
        result["load"] = os.getloadavg()[0]
        (OUT.parent / f"learning_{name}.json").write_text(json.dumps(result, indent=1))
        print(f"{name}: done ({time.perf_counter() - start:.0f} s)", flush=True)
    # The report covers every scene measured so far (runs may be split by --scenes).
    results = [
        json.loads(p.read_text())
        for name in TASKS
        if (p := OUT.parent / f"learning_{name}.json").exists()
    ]
    text = report(results, opts.draws, time.perf_counter() - start)
    OUT.write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
