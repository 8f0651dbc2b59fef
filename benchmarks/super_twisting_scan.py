r"""The super-twisting family beyond the campaign's grid: where its error comes from.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.super_twisting_scan            # BE and the pair
    OPENBLAS_NUM_THREADS=1 python -m benchmarks.super_twisting_scan --steppers Bathe

27 points (gains $c$, $L$ and initial states $x_0$) x rtol 1e-3 to 1e-6, semismooth Newton,
the default controller, judged by the campaign's rule (`benchmarks.reliability.judge`).
Beside the error, per run:

- `shift`: the time the run enters sliding for good (its selection inside $(-1, 1)$ from
  there on) minus the exact accumulation time $T^*$ of the switchings;
- `inherited`: the accumulation time of the *exact* flow from the run's state at its last
  accepted point before $T^* - 0.1$, minus $T^*$: the part of `shift` made before the
  last switchings (equal to `shift` when the steps through them add nothing);
- `zeno`: the error over the run's points within 0.1 of $T^*$ (where the error of
  $\nu = -k_2 \int w$ is about $2 k_2$ `shift` once `shift` is smaller than the last
  twisting, and capped by its size before), `before`: the error over the earlier ones
  (with $c = 3$ the twisting starts earlier than $T^* - 0.1$, and so does the cap).

The reference assumes sliding lasts from $T^*$ on; it does at every point here (the
equivalent selection $(d' + c^3 x_1)/k_2$ stays at most 0.96 in modulus).

Writes `benchmarks/results/super_twisting_scan.md` (`--out`; the trapezoidal rule and
Bathe's run is `results/super_twisting_scan_second_order.md`).
"""

import argparse
import itertools
import os
import time
from pathlib import Path

import numpy as np


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import nivpjax as nj  # noqa: E402

from . import reliability as campaign  # noqa: E402
from .families import FAMILIES, _floats, super_twisting_reference  # noqa: E402


OUT = Path(__file__).resolve().parent / "results" / "super_twisting_scan.md"
POINTS = tuple(
    {"c": c, "L": L, "x0": x0}
    for c, L, x0 in itertools.product(
        (0.5, 1.0, 3.0), (1.5, 3.0, 5.0), ((0.5, 0.0), (1.0, -0.5), (-0.3, 0.8))
    )
)
ZONE = 0.1


def accumulation(x0, t0, a, t1=10.0):
    """The accumulation time $T^*$ of the exact flow from `x0` at `t0` (NaN where the
    reference finds none before `t1`)."""
    grid = np.array([t0, t1])
    try:
        return super_twisting_reference(x0, a["k1"], a["k2"], a["c"], grid, t0=t0)[2]
    except RuntimeError:
        return np.nan


def diagnose(family, scene, sol, point):
    """The campaign's error and `shift`, `inherited`, `zeno`, `before` of one successful
    run (module doc)."""
    _, x0, args = family.make(point)
    a = _floats(args)
    t_star = accumulation(np.asarray(x0), 0.0, a)
    k = int(sol.n_accepted)
    ts = np.asarray(sol.ts[: k + 1])
    xs, ms = scene.split(np.asarray(sol.ys[: k + 1]))
    held = np.abs(np.ravel(np.asarray(ms["w"]))) < 1.0
    entry = k + 1
    while entry > 0 and held[entry - 1]:
        entry -= 1
    errors = family.point_errors(point, ts, xs)
    zone = np.abs(ts - t_star) <= ZONE
    j = max(np.searchsorted(ts, t_star - ZONE) - 1, 0)
    return dict(
        error=float(errors.max()),
        shift=(ts[entry] if entry <= k else np.nan) - t_star,
        inherited=accumulation(xs[j], ts[j], a) - t_star if j > 0 else np.nan,
        zeno=float(errors[zone].max()) if zone.any() else np.nan,
        before=float(errors[ts < t_star - ZONE].max()) if j > 0 else np.nan,
    )


def scan(steppers, rtols, log=print):
    family = FAMILIES["super_twisting"]
    rows = []
    for stepper in steppers:
        scene, run = campaign.compiled_run(family, stepper, "SSN", "default")
        for g, point in enumerate(POINTS):
            _, x0, args = family.make(point)
            runs = []
            for rtol in rtols:
                sol, _ = run(x0, args, rtol)
                ok = bool(sol.result == nj.RESULTS.successful)
                row = dict(stepper=stepper, point=g, rtol=rtol, ok=ok, error=np.nan)
                row.update(result=int(sol.result._value), accepted=int(sol.n_accepted))
                if ok:
                    row.update(diagnose(family, scene, sol, point))
                runs.append(row)
            campaign.judge(family, campaign.STEPPERS[stepper][1], runs)
            log(f"{stepper:13s} {g:2d} {point} " + " ".join(_cell(r) for r in runs))
            rows += runs
    return rows


def _cell(r):
    if not r["ok"]:
        return "stall"
    forgiven = r["verdict"] == "pass" and r["why"]  # a short fall, then proportional
    mark = {"pass": "p", "wrong": "W"}[r["verdict"]] + ("*" if forgiven else "")
    return f"{mark}:{r['ratio']:.2f}"


def table(rows):
    lines = [
        "| stepper | point | c | L | x0 | rtol | verdict | error / bound | before | zeno "
        "| shift | inherited | steps |",
        "|---" * 13 + "|",
    ]
    for r in rows:
        p = POINTS[r["point"]]
        if not r["ok"]:
            lines.append(
                f"| {r['stepper']} | {r['point']} | {p['c']} | {p['L']} | {p['x0']} "
                f"| {r['rtol']:.0e} | stall ({r['result']}) | | | | | | {r['accepted']} |"
            )
            continue
        verdict = r["verdict"] + (" (short fall, then proportional)" if r["why"] else "")
        if r["verdict"] == "wrong":
            verdict = f"**wrong**: {r['why']}"
        lines.append(
            f"| {r['stepper']} | {r['point']} | {p['c']} | {p['L']} | {p['x0']} "
            f"| {r['rtol']:.0e} | {verdict} | {r['ratio']:.2f} | {r['before']:.2e} "
            f"| {r['zeno']:.2e} | {r['shift']:+.2e} | {r['inherited']:+.2e} | {r['accepted']} |"
        )
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks.super_twisting_scan")
    parser.add_argument(
        "--steppers",
        nargs="+",
        choices=list(campaign.STEPPERS),
        default=["BackwardEuler", "EmbeddedBETR"],
    )
    parser.add_argument("--out", default=str(OUT))
    a = parser.parse_args(argv)
    t0 = time.perf_counter()
    rows = scan(a.steppers, campaign.QUICK_RTOLS)
    count = {v: sum(r["verdict"] == v for r in rows) for v in ("pass", "stall", "wrong")}
    short = sum(bool(r["why"]) and r["verdict"] == "pass" for r in rows)
    head = (
        f"Super-twisting scan of {time.strftime('%Y-%m-%d')} ({', '.join(a.steppers)}; SSN, "
        f"default controller; {len(POINTS)} points x rtol 1e-3 to 1e-6): {len(rows)} runs, "
        f"{count['pass']} passed ({short} after a short fall out of a capped error), "
        f"{count['stall']} stalled, {count['wrong']} silently wrong; "
        f"{(time.perf_counter() - t0) / 60:.0f} min."
    )
    Path(a.out).write_text(f"{head}\n\n{table(rows)}\n")
    print(head)


if __name__ == "__main__":
    main()
