"""Calibration benchmark: accuracy of derivatives across switches, and what they cost.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.calibration --label after
    OPENBLAS_NUM_THREADS=1 python -m benchmarks.calibration --label after --cost

1. Accuracy: the relative error (max norm over the Jacobian) of the derivative of the final
   state with respect to the parameters, against the exact derivative of the continuous
   problem, per scene and per rtol. The scenes, their compiled Jacobians (Bathe, PID
   controller, reverse mode) and exact references are those of
   `tests/test_sensitivities.py` (loaded from there, so the table measures exactly what the
   tests check), plus the ball of `tests/test_event_gradients.py`:

   - `slider`: spring-slider, constant friction, d(s, v)(5)/d mu (two slip reversals);
   - `weakening`: driven slider with slip-weakening friction, d(s, v)(8)/d(mu_s, mu_k, Dc)
     (breakaway, slip to stick, breakaway);
   - `relay crossing`: x' = -sign x + b, d x(1)/d(x0, b, a) across a transversal switch;
   - `relay sliding`: x' = -sign x + 1.5 sin t, d x(2)/d(x0, b, a) after entering and
     leaving sliding;
   - `rectifier`: d v(15 ms)/d(C, R_L) after the diode turns off;
   - `plastic`: a ball with e = 0 landing and lifted off again, d(q, v)(1)/d(H, g, a);
   - `ball`: restitution, d(q, v)(1)/d(e, g) after one impact.

   Run it once with today's code on `PYTHONPATH` (`--label before`) and once with this
   branch (`--label after`); the second run writes the combined table to
   `benchmarks/results/calibration.md`.

2. Cost (`--cost`): `jax.value_and_grad` of the trajectory losses of `benchmarks.gradients`
   against the forward solve, and `jax.jacfwd` of a residual vector (the slip-weakening
   slider's s(t) at 60 times) per parameter against the forward solve.
"""

import argparse
import importlib.util
import json
import os
import sys
import time
from pathlib import Path


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402


jax.config.update("jax_enable_x64", True)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
RTOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)


def _load(name):
    path = ROOT / "tests" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"_bench_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _cases():
    t = _load("test_sensitivities")
    g = _load("test_event_gradients")
    import nivpjax as nj

    fd = t._central_jacobian

    weak_q = np.array([t.WEAK["mu_s"], t.WEAK["mu_k"], t.WEAK["Dc"]])
    # The relay crossing as in its test: at a = 0 the solution is piecewise linear and the
    # error control does not resolve d/da (see the test), so a = 0.3.
    x0, b, a, T = -0.5, 1.5, 0.3, 1.0
    _, crossing = t._relay_crossing_exact(x0, b, a, T)
    t_e = np.arcsin(1 / 1.5)
    plastic_p = jnp.array([0.2, 9.81, 19.62])
    ball_p = jnp.array([0.8, 9.81])

    @jax.jit
    def ball_jac(p, rtol):
        scene, y0, _ = nj.scenes.bouncing_ball(height=g.H)

        def final(q):
            return t._solve_final(scene, y0, {"e": q[0], "g": q[1]}, g.T, rtol, nj.Bathe())

        return t._jacobian(final, p)

    return {
        "slider": (
            lambda r: t._slider_jac(0.2, r),
            fd(lambda q: t._slider_exact(float(q[0])), [0.2], 1e-6)[:, 0],
        ),
        "weakening": (
            lambda r: t._weakening_jac(jnp.asarray(weak_q), r),
            fd(t._weakening_exact, weak_q, 1e-5),
        ),
        "relay crossing": (lambda r: t._relay_jac(jnp.array([x0, b, a]), T, r), crossing),
        "relay sliding": (
            lambda r: t._relay_jac(jnp.array([0.1, 0.0, 1.5]), 2.0, r),
            np.array([0.0, 2.0 - t_e, np.cos(t_e) - np.cos(2.0)]),
        ),
        "rectifier": (
            lambda r: t._rectifier_jac(jnp.array([1.0, 1.0]), r),
            fd(t._rectifier_exact, [1.0, 1.0], 1e-6),
        ),
        "plastic": (
            lambda r: t._plastic_jac(plastic_p, r),
            np.asarray(jax.jacfwd(t._plastic_exact)(plastic_p)),
        ),
        "ball": (
            lambda r: ball_jac(ball_p, r),
            np.asarray(jax.jacfwd(lambda p: g._exact(*p))(ball_p)),
        ),
    }


def accuracy(scenes, log):
    import nivpjax as nj

    rows = {}
    for name, (jac_fn, exact) in _cases().items():
        if scenes and name not in scenes:
            continue
        rows[name] = {}
        for rtol in RTOLS:
            t0 = time.perf_counter()
            jac, _, result = jax.block_until_ready(jac_fn(rtol))
            ok = bool(result == nj.RESULTS.successful)
            err = float(np.max(np.abs(np.asarray(jac) - exact)) / np.max(np.abs(exact)))
            rows[name][f"{rtol:g}"] = err if ok else None
            seconds = time.perf_counter() - t0
            log(f"[accuracy {name}] rtol {rtol:g}: rel. error {err:.2e} ({seconds:.1f} s)")
    return rows


def cost(log):
    from . import gradients
    from ._common import compile_timed, median_time

    out = {}
    for name in ("ball", "slider"):
        row = gradients.run_problem(name, quick=True, log=log)
        out[f"value_and_grad / forward, {name}"] = row["ratio"]
    t = _load("test_sensitivities")
    import nivpjax as nj

    scene, x0, args = nj.scenes.spring_slider(velocity=0.0)
    base = {k: jnp.asarray(v) for k, v in t.WEAK.items()}
    times = jnp.linspace(0.2, 12.0, 60)

    def slip(q):
        a = dict(base, mu_s=q[0], mu_k=q[1], Dc=q[2])
        sol = scene.solve(
            0.0,
            12.0,
            x0,
            a,
            stepper=nj.Bathe(),
            controller=nj.PIDController(rtol=1e-6, atol=1e-9),
            t_eval=times,
            max_steps=4096,
            adjoint="forward",
            throw=False,
        )
        return sol.y_eval[:, 0]

    q = jnp.array([0.6, 0.4, 0.5])
    fwd, _ = compile_timed(slip, q)
    jf, _ = compile_timed(jax.jacfwd(slip), q)
    t_fwd, _ = median_time(fwd, q, repeats=5)
    t_jf, _ = median_time(jf, q, repeats=5)
    out["jacfwd (3 parameters) / forward, weakening slider"] = t_jf / t_fwd
    out["jacfwd per parameter / forward, weakening slider"] = t_jf / t_fwd / 3
    log(f"[cost] forward {t_fwd * 1e3:.2f} ms, jacfwd {t_jf * 1e3:.2f} ms")
    return out


def _table(results):
    labels = [k for k in ("before", "after") if k in results]
    names = list(results[labels[-1]]["accuracy"])
    lines = [
        "# Calibration: derivative accuracy and cost",
        "",
        "Written by `python -m benchmarks.calibration` (see its docstring). Relative error "
        "(max norm over the Jacobian) of the derivative of the final state against the "
        "exact derivative of the continuous problem; Bathe + semismooth Newton, PID "
        "controller at `rtol` (atol = rtol/1000), reverse mode. `before`: the code before "
        "the switch sensitivities (impacts only); `after`: this version. "
        + "; ".join(
            f"`{label}` measured {results[label]['measured']}"
            for label in labels
            if results[label].get("measured")
        )
        + ".",
        "",
        "| scene | version | " + " | ".join(f"rtol {r:g}" for r in RTOLS) + " |",
        "|---|---|" + "---|" * len(RTOLS),
    ]
    for name in names:
        for label in labels:
            if name not in results[label]["accuracy"]:
                continue
            row = results[label]["accuracy"][name]
            cells = [row.get(f"{r:g}") for r in RTOLS]
            fmt = ["failed" if c is None else f"{c:.1e}" for c in cells]
            lines.append(f"| {name} | {label} | " + " | ".join(fmt) + " |")
    for label in labels:
        if results[label].get("cost"):
            lines += ["", f"Cost ({label}):", "", "| measure | ratio |", "|---|---|"]
            for k, v in results[label]["cost"].items():
                lines.append(f"| {k} | {v:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks.calibration")
    parser.add_argument("--label", default="after", choices=["before", "after"])
    parser.add_argument("--scenes", nargs="*")
    parser.add_argument("--cost", action="store_true")
    parser.add_argument("--skip-accuracy", action="store_true")
    args = parser.parse_args(argv)
    log = lambda msg: print(msg, flush=True)
    path = RESULTS / "calibration.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    entry = results.setdefault(args.label, {"accuracy": {}, "cost": {}})
    if not args.skip_accuracy:
        entry["accuracy"].update(accuracy(args.scenes, log))
    if args.cost:
        entry["cost"] = cost(log)
    entry["measured"] = (
        f"{time.strftime('%Y-%m-%d %H:%M')} ({os.cpu_count()} CPUs, load average "
        f"{os.getloadavg()[0]:.2f} at the end)"
    )
    path.write_text(json.dumps(results, indent=1))
    (RESULTS / "calibration.md").write_text(_table(results))
    print(_table(results))


if __name__ == "__main__":
    sys.exit(main())
