"""The reliability campaign: does a `successful` result meet its tolerance?

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.reliability           # full (about an hour)
    OPENBLAS_NUM_THREADS=1 python -m benchmarks.reliability --quick   # minutes

In the spirit of the DETEST and Bari test sets for smooth solvers: scene families with exact
(or converged event-driven) references and parameter grids, run with every stepper x
{semismooth Newton, VI} x {the default controller, PI control, the reference package's
controller options} x rtol from 1e-2 to 1e-8 (atol = rtol / 100).

**The rule**, stated per family before the run: a run either returns a failure code (a
*stall*: reported, not wrong), or its global error meets tolerance proportionality,

    error <= C_family * rtol^q,   q = p / (p + 1) for a scheme of order p,

(the global error of a scheme of order p under control of its local error per step; less
where the family's problem allows less whatever the scheme: `Family.rate`, 1/2 on
super-twisting, whose accumulation time moves like the square root of an error), and
its error falls as rtol does: each time rtol falls by 10 the error falls by at least
10^q / 2 (the expected rate within 2x), unless it is already below a tenth of its bound
(round-off and the event margin set floors there, far inside tolerance), or the fall is
the way out of a capped error: the next decade falls at the expected rate (see
`_proportional_after`; the finest run has none, and a short fall into it stays wrong).
A successful run that breaks either is a *silent wrong answer*.

Writes `benchmarks/results/reliability.{csv,md,png}` and the table of
`docs/concepts/guarantees.md`.
"""

import argparse
import csv
import itertools
import os
import time
from pathlib import Path

import numpy as np


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import nivpjax as nj  # noqa: E402
from nivpjax._model import Model  # noqa: E402
from nivpjax._projector import ProjectionContext  # noqa: E402
from nivpjax._validate import check_mass_matrix  # noqa: E402

from .families import FAMILIES  # noqa: E402


jax.config.update("jax_enable_x64", True)

RESULTS = Path(__file__).resolve().parent / "results"
DOCS_PAGE = Path(__file__).resolve().parents[1] / "docs" / "concepts" / "guarantees.md"
RTOLS = tuple(10.0**-k for k in range(2, 9))
QUICK_RTOLS = (1e-3, 1e-4, 1e-5, 1e-6)
# The budget (its trapezoidal relay "exhausts 100 000 steps"). At 50 000 the
# first-order schemes' relay at rtol 1e-6 under PI control stalled on the budget alone
# (45 000 steps with the default controller, 57 550 with PI, at the grid's third point).
MAX_STEPS = 100_000
# First-order schemes stop at this rtol: below it they need 1e5 to 1e6 steps over these
# horizons (global error ~ rtol^(1/2)), stalls by construction that cost minutes each.
FIRST_ORDER_MIN_RTOL = 1e-6

STEPPERS = {  # name: (class, order of the propagated solution)
    "BackwardEuler": (nj.BackwardEuler, 1),
    "Trapezoidal": (nj.Trapezoidal, 2),
    "Bathe": (nj.Bathe, 2),
    "EmbeddedBETR": (nj.EmbeddedBETR, 1),
}
SOLVERS = {"SSN": nj.SemismoothNewton, "VI": nj.FixedPointVI}


def controller(name, rtol, h_max):
    """The three controllers of the campaign at `rtol` (atol = rtol / 100).

    - `default`: `PIDController` as a user gets it (integral control, event prediction);
    - `PI`: the Gustafsson PI filter (0.4, 0.3) of the reference's default `use_PI=True`;
    - `reference`: the reference package's options that the issue names, `h_down=0.5,
      h_up=1.5, method_order=1, use_PI=False`, as the drop-in translates them.
    """
    common = dict(rtol=rtol, atol=rtol / 100, h_max=h_max)
    if name == "default":
        return nj.PIDController(**common)
    if name == "PI":
        return nj.PIDController(pcoeff=0.4, icoeff=0.3, **common)
    return nj.PIDController(
        pcoeff=0.0, icoeff=1.0, factormin=0.5, factormax=1.5, error_order=2, h_min=1e-10, **common
    )


CONTROLS = ("default", "PI", "reference")


# Output times per run (`t_eval`), evenly spread over the horizon.
N_EVAL = 401


def compiled_run(family, stepper, solver, control, outputs=False):
    """One jitted solve per configuration: `run(x0, args, rtol) -> (Solution, outside)`
    (the parameters of the grid are run-time inputs); with `outputs`, `N_EVAL` output
    times and the largest distance of an output value from its set (`outside_of_sets`),
    else no output times and `outside` NaN."""
    scene, _, _ = family.make(family.grid[0])
    step = STEPPERS[stepper][0](solver=SOLVERS[solver]())
    t_eval = jnp.linspace(0.0, family.t1, N_EVAL) if outputs else None

    def run(x0, args, rtol):
        sol = scene.solve(
            0.0,
            family.t1,
            x0,
            args,
            stepper=step,
            controller=controller(control, rtol, family.h_max),
            max_steps=MAX_STEPS,
            throw=False,
            t_eval=t_eval,
        )
        if not outputs:
            return sol, jnp.full((), jnp.nan, sol.ys.dtype)
        return sol, outside_of_sets(scene, sol, args)

    return scene, jax.jit(run)


def outside_of_sets(scene, sol, args):
    r"""The largest distance of an output value at `t_eval` from its set, relative to
    $1 + |v|$ (0 when every value lies in its set bit for bit; `nan` for scenes with
    impulses, whose sets are not projections of the state):

    - states on the rows a projection acts on (not a proximal map's): $|P(y) - y|$;
    - reactions on the differential rows a set can hold (`Model.held_rows`):
      $|P(y - r) - y|$ ($-r$ in the normal cone of the set at $y$: zero inside, pointing
      out of a face the state is on);
    - reactions on a proximal map's rows (friction): the distance of $r$ from the map's
      reaction set, its bound (`Model.project_reaction`)."""
    y_eval, r_eval = sol.y_eval, sol.multipliers_eval
    n = y_eval.shape[1]
    mass, algebraic = check_mass_matrix(scene.full_mass_matrix, n, y_eval.dtype)
    model = Model.build(
        scene.vector_field, scene.projector, mass, algebraic, equation_rows=scene.equation_rows
    )
    if model.has_impulses:
        return jnp.full((), jnp.nan, y_eval.dtype)
    acts = jnp.asarray(model.projector.acts_on(n)) & ~model.weighed
    held = model.held_rows

    def one(t, y, r):
        ctx = ProjectionContext(
            t=t, h=jnp.ones_like(t), y_prev=y, y_iter=y, rho=jnp.ones_like(y), args=args
        )
        state = jnp.where(acts, jnp.abs(model.projector(y, ctx) - y), 0.0)
        moved = jnp.where(held, jnp.abs(model.projector(y - r, ctx) - y), 0.0)
        bound = jnp.abs(model.project_reaction(t, y, r, args) - r)
        scale = 1.0 + jnp.abs(jnp.concatenate([y, r]))
        gaps = jnp.concatenate([jnp.maximum(state, moved), bound]) / scale
        return jnp.max(jnp.where(jnp.isfinite(gaps), gaps, 0.0))

    return jnp.max(jax.vmap(one)(sol.t_eval, y_eval, r_eval))


def teval_ratio(family, params, scene, sol, ts, xs, rtol):
    """The worst, over the output times, of the `t_eval` error to the larger error of the
    two accepted steps around it (issue 31's target: at most 2); step errors below
    `1e-4 rtol` count as that (round-off and exact rests would make any ratio)."""
    t_eval = np.asarray(sol.t_eval)
    xs_eval, _ = scene.split(np.asarray(sol.y_eval))
    k = len(ts) - 1
    errs = family.errors_at(
        params, np.concatenate([ts, t_eval]), np.concatenate([xs, xs_eval], axis=0)
    )
    step_err, eval_err = errs[: k + 1], errs[k + 1 :]
    i = np.clip(np.searchsorted(ts, t_eval, side="right") - 1, 0, max(k - 1, 0))
    around = np.maximum(step_err[i], step_err[np.minimum(i + 1, k)])
    return float(np.max(eval_err / np.maximum(around, 1e-4 * rtol)))


def run_one(family, scene, run, params, rtol):
    """`dict` of one run: result, error, steps, seconds, the `t_eval` ratio
    (`teval_ratio`) and the largest distance of an output value from its set
    (`outside_of_sets`); both NaN for a run without output times."""
    _, x0, args = family.make(params)
    t0 = time.perf_counter()
    sol, outside = jax.block_until_ready(run(x0, args, rtol))
    seconds = time.perf_counter() - t0
    ok = bool(sol.result == nj.RESULTS.successful)
    k = int(sol.n_accepted)
    ts = np.asarray(sol.ts[: k + 1])
    xs, _ = scene.split(np.asarray(sol.ys[: k + 1]))
    error = family.error(params, ts, xs) if ok else np.nan
    ratio = np.nan
    if ok and sol.t_eval is not None:
        ratio = teval_ratio(family, params, scene, sol, ts, xs, rtol)
    return dict(
        ok=ok,
        result=int(sol.result._value),
        error=error,
        accepted=k,
        rejected=int(sol.n_rejected),
        seconds=seconds,
        teval_ratio=ratio,
        outside=float(outside) if ok else np.nan,
    )


def judge(family, order, rows):
    """Classify the runs of one (configuration, grid point) across rtol, in place:
    `verdict` is `pass`, `stall` or `wrong` (with `why`)."""
    q, C = family.q(order), family.constant(order)
    for row in rows:
        bound = C * row["rtol"] ** q
        row["ratio"] = row["error"] / bound if row["ok"] else np.nan
        if not row["ok"]:
            row["verdict"], row["why"] = "stall", "failure code"
        elif not np.isfinite(row["error"]) or row["error"] > bound:
            row["verdict"], row["why"] = "wrong", "error above C rtol^q"
        else:
            row["verdict"], row["why"] = "pass", ""
    for coarse, fine, finer in zip(rows, rows[1:], rows[2:] + [None]):
        if not (coarse["ok"] and fine["ok"]) or fine["verdict"] == "wrong":
            continue
        inside = fine["error"] <= 0.1 * C * fine["rtol"] ** q
        if inside or _falls(coarse, fine, q):
            continue
        if _proportional_after(fine, finer, q, C):
            fine["why"] = "short fall before a proportional one (coarser error capped)"
        else:
            fine["verdict"], fine["why"] = "wrong", "error does not fall with rtol"
    return rows


def _falls(coarse, fine, q):
    # The error falls by at least 10^q / 2 from `coarse` to `fine` (rtol / 10).
    return fine["error"] <= 2 * 10.0**-q * coarse["error"]


def _proportional_after(fine, finer, q, C):
    r"""Whether a short fall into `fine` is the end of a coarser run's capped error, not a
    wrong limit: the next run (`finer`, rtol / 10) succeeds within its bound and falls
    from `fine` at the expected rate. An error that stops falling, towards a wrong
    limit, falls short in every later decade too; one capped at loose tolerances (by
    the size of a structure it cannot exceed, e.g. the last switchings before a Zeno
    point) falls short once and proportionally after. The finest run has no later one:
    a short fall into it stays wrong."""
    return (
        finer is not None
        and finer["ok"]
        and finer["error"] <= C * finer["rtol"] ** q
        and _falls(fine, finer, q)
    )


def campaign(families, steppers, solvers, controls, rtols, grid_slice, log=print):
    rows = []
    for family, stepper, solver, control in itertools.product(
        families, steppers, solvers, controls
    ):
        t0 = time.perf_counter()
        runs = run_config(family, stepper, solver, control, rtols, grid_slice)
        log(
            f"{family.name:15s} {stepper:13s} {solver:3s} {control:9s} "
            + " ".join(r["verdict"][0] for r in runs)
            + f"  {time.perf_counter() - t0:6.1f} s"
        )
        rows += runs
    return rows


def run_config(family, stepper, solver, control, rtols, grid_slice):
    """The judged runs of one configuration over its grid points and tolerances."""
    order = STEPPERS[stepper][1]
    scene, run = compiled_run(family, stepper, solver, control, outputs=True)
    rows = []
    for g, params in enumerate(family.grid[grid_slice]):
        runs = []
        for rtol in rtols:
            if order == 1 and rtol < FIRST_ORDER_MIN_RTOL:
                continue
            row = run_one(family, scene, run, params, rtol)
            row.update(family=family.name, stepper=stepper, solver=solver, control=control)
            row.update(point=g, rtol=rtol)
            runs.append(row)
        rows += judge(family, order, runs)
    return rows


# --- Output ------------------------------------------------------------------------------


FIELDS = (
    "family stepper solver control point rtol verdict why error ratio accepted rejected "
    "result seconds teval_ratio outside"
).split()


def read_runs(paths):
    """The runs of campaign CSVs, judged again by today's rule (`judge`)."""
    rows = []
    for path in paths:
        with open(path) as fh:
            for r in csv.DictReader(fh):
                ok = r["verdict"] != "stall"
                rows.append(
                    dict(
                        r,
                        rtol=float(r["rtol"]),
                        error=float(r["error"]) if ok else np.nan,
                        ok=ok,
                        accepted=int(r["accepted"]),
                        rejected=int(r["rejected"]),
                        seconds=float(r["seconds"]),
                        teval_ratio=float(r.get("teval_ratio") or "nan"),
                        outside=float(r.get("outside") or "nan"),
                    )
                )
    key = lambda r: (r["family"], r["stepper"], r["solver"], r["control"], r["point"])  # noqa: E731
    judged = []
    for group in _groups(sorted(rows, key=key), key):
        group.sort(key=lambda r: -r["rtol"])
        judged += judge(FAMILIES[group[0]["family"]], STEPPERS[group[0]["stepper"]][1], group)
    return judged


def _groups(rows, key):
    out = {}
    for r in rows:
        out.setdefault(key(r), []).append(r)
    return list(out.values())


def write_csv(rows, path):
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, FIELDS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{r[k]:.3e}" if isinstance(r[k], float) else r[k]) for k in FIELDS})


def summary(rows, families):
    """Markdown: per family x stepper, runs passed / stalled / silently wrong, the worst
    error/bound ratio of a successful run, the median accepted steps, the worst `t_eval`
    ratio (`teval_ratio`: issue 31's target is 2) and the largest distance of an output
    value from its set (`outside_of_sets`; `-` for scenes with impulses)."""
    lines = [
        "| family | effect | C | stepper | q | runs | pass | stall | wrong "
        "| worst error / bound | median steps | worst `t_eval` ratio | outside sets |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for family in families:
        for stepper, (_, order) in STEPPERS.items():
            sel = [r for r in rows if r["family"] == family.name and r["stepper"] == stepper]
            if not sel:
                continue
            count = {v: sum(r["verdict"] == v for r in sel) for v in ("pass", "stall", "wrong")}
            ratios = [r["ratio"] for r in sel if r["ok"]]
            worst = f"{max(ratios):.2f}" if ratios else "-"
            steps = int(np.median([r["accepted"] for r in sel]))
            lines.append(
                f"| {family.name} | {family.effect} | {family.constant(order):g} | {stepper} "
                f"| {family.q(order):.2f} | {len(sel)} | {count['pass']} | {count['stall']} "
                f"| {count['wrong']} | {worst} | {steps} | {_worst(sel, 'teval_ratio', '.2f')} "
                f"| {_worst(sel, 'outside', '.1e')} |"
            )
    total = {v: sum(r["verdict"] == v for r in rows) for v in ("pass", "stall", "wrong")}
    lines.append(
        f"\n**All:** {len(rows)} runs, {total['pass']} passed, {total['stall']} stalled "
        f"(failure code), {total['wrong']} silently wrong."
    )
    return "\n".join(lines)


def _worst(rows, key, fmt):
    values = [r.get(key, np.nan) for r in rows if r["ok"]]
    values = [v for v in values if np.isfinite(v)]
    return format(max(values), fmt) if values else "-"


def wrong_list(rows):
    bad = [r for r in rows if r["verdict"] == "wrong"]
    if not bad:
        return "No silent wrong answer."
    head = "| family | stepper | solver | control | point | rtol | error | why |"
    lines = [head, "|---" * 8 + "|"]
    for r in bad:
        lines.append(
            f"| {r['family']} | {r['stepper']} | {r['solver']} | {r['control']} | {r['point']} "
            f"| {r['rtol']:.0e} | {r['error']:.2e} | {r['why']} |"
        )
    return "\n".join(lines)


def plot(rows, families, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = 4
    nrows = -(-len(families) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4 * cols, 3.2 * nrows), squeeze=False)
    for ax, family in zip(axes.flat, families):
        for stepper, (_, order) in STEPPERS.items():
            sel = [
                r
                for r in rows
                if r["family"] == family.name
                and r["stepper"] == stepper
                and r["solver"] == "SSN"
                and r["control"] == "default"
                and r["ok"]
            ]
            rt = sorted({r["rtol"] for r in sel})
            worst = [max(r["error"] for r in sel if r["rtol"] == x) for x in rt]
            ax.loglog(rt, worst, "o-", ms=3, label=stepper)
        rt = np.array(sorted({r["rtol"] for r in rows}))
        for order, style in ((1, ":"), (2, "--")):
            ax.loglog(rt, family.constant(order) * rt ** family.q(order), "k" + style, lw=0.8)
        ax.set_title(family.name, fontsize=9)
        ax.set_xlabel("rtol")
        ax.invert_xaxis()
    for ax in list(axes.flat)[len(families) :]:
        ax.axis("off")
    axes.flat[0].set_ylabel("worst error over the grid")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(
        "Error against rtol (semismooth Newton, default controller); "
        "dotted/dashed: the bounds C rtol^q for q = 1/2, 2/3",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def write_docs(table, wrong, header):
    text = DOCS_PAGE.read_text()
    start, end = "<!-- reliability-table -->", "<!-- /reliability-table -->"
    i, j = text.index(start) + len(start), text.index(end)
    body = f"\n{header}\n\n{table}\n\n{wrong}\n"
    DOCS_PAGE.write_text(text[:i] + body + text[j:])


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks.reliability")
    parser.add_argument("--quick", action="store_true", help="4 rtols, first grid point")
    parser.add_argument("--families", nargs="+", choices=list(FAMILIES), default=list(FAMILIES))
    parser.add_argument("--steppers", nargs="+", choices=list(STEPPERS), default=list(STEPPERS))
    parser.add_argument("--solvers", nargs="+", choices=list(SOLVERS), default=list(SOLVERS))
    parser.add_argument("--controls", nargs="+", choices=CONTROLS, default=list(CONTROLS))
    parser.add_argument("--out", default=None, help="file stem (default: results/reliability)")
    parser.add_argument("--no-docs", action="store_true", help="do not rewrite the docs page")
    parser.add_argument(
        "--merge",
        nargs="+",
        metavar="CSV",
        help="judge and report the runs of earlier CSVs (shards run in parallel) instead",
    )
    a = parser.parse_args(argv)
    families = [FAMILIES[f] for f in a.families]
    rtols = QUICK_RTOLS if a.quick else RTOLS
    grid = slice(0, 1) if a.quick else slice(None)
    t0 = time.perf_counter()
    if a.merge:
        rows = read_runs(a.merge)
        families = [f for f in families if any(r["family"] == f.name for r in rows)]
    else:
        rows = campaign(families, a.steppers, a.solvers, a.controls, rtols, grid)
    minutes = (time.perf_counter() - t0) / 60
    stem = Path(a.out) if a.out else RESULTS / ("reliability-quick" if a.quick else "reliability")
    write_csv(rows, stem.with_suffix(".csv"))
    plot(rows, families, stem.with_suffix(".png"))
    table, wrong = summary(rows, families), wrong_list(rows)
    seconds = sum(r["seconds"] for r in rows)
    header = (
        f"Campaign {'(quick) ' if a.quick else ''}of {time.strftime('%Y-%m-%d')}: "
        f"nivpjax {nj.__version__}, rtols {', '.join(f'{r:.0e}' for r in rtols)} "
        f"(first-order schemes down to {FIRST_ORDER_MIN_RTOL:.0e}), max_steps {MAX_STEPS}; "
        f"{seconds / 60:.0f} min of runs (compilation excluded)"
        + ("" if a.merge else f", {minutes:.0f} min in all on {os.cpu_count()} cores")
        + "."
    )
    stem.with_suffix(".md").write_text(f"{header}\n\n{table}\n\n{wrong}\n")
    if not (a.no_docs or a.quick or a.out):
        write_docs(table, wrong, header)
    print(table)
    print(wrong)


if __name__ == "__main__":
    main()
