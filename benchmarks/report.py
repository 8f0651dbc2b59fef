"""Outputs of the suite: a CSV and a work-precision PNG per scene, the generated markdown
(benchmarks/results/README.md) and the short headline copy for the docs
(docs/benchmarks.md)."""

import csv
import os

import matplotlib
import numpy as np


matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ._common import fmt_num, fmt_time, markdown_table  # noqa: E402
from .work_precision import EQUAL_ERR_SLACK, REF_BROKEN, REG_TARGET_ERR  # noqa: E402


HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS_DIR = os.path.join(HERE, "results")
DOCS_FILE = os.path.join(os.path.dirname(HERE), "docs", "benchmarks.md")

REF_TARGET = 30.0
BATCH_TARGET = 1000.0
BATCH_TARGET_N = 10000
GRAD_TARGET = 5.0
CSV_FIELDS = [
    "scene",
    "family",
    "method",
    "regularisation",
    "rtol",
    "atol",
    "error",
    "time",
    "compile",
    "accepted",
    "rejected",
    "iterations",
    "rhs_evals",
    "status",
]


def _ratio(x):
    if x is None or not np.isfinite(x):
        return "n/a"
    return f"{x:.0f}x" if x >= 10 else f"{x:.2g}x"


def _steps(r):
    acc = "-" if r["accepted"] is None else str(r["accepted"])
    rej = "-" if r["rejected"] is None else str(r["rejected"])
    return f"{acc}/{rej}"


def _method(r):
    reg = f" [{r['regularisation']}]" if r["regularisation"] else ""
    return f"{r['method']}{reg}"


# --- per scene: CSV, PNG, tables -------------------------------------------------------------
def write_csv(res, folder):
    path = os.path.join(folder, f"{res['case'].name}.csv")
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_FIELDS)
        w.writeheader()
        for r in res["rows"]:
            w.writerow({k: r.get(k) for k in CSV_FIELDS})
    return path


_FAMILY_STYLE = {
    "nivpjax": dict(ls="-", lw=1.8),
    "reference": dict(ls="-", lw=2.5, color="black"),
    "diffrax": dict(ls="--", lw=1.2),
    "scipy": dict(ls=":", lw=1.6),
}
_FAMILY_ORDER = {"nivpjax": 0, "reference": 1, "diffrax": 2, "scipy": 3}
_NJ_COLORS = [
    "tab:blue",
    "tab:orange",
    "tab:green",
    "tab:red",
    "tab:olive",
    "tab:cyan",
    "navy",
    "gold",
]
_OTHER_COLORS = {
    "diffrax Kvaerno5": "darkviolet",
    "diffrax Tsit5": "saddlebrown",
    "scipy BDF": "deeppink",
    "scipy Radau": "dimgray",
}
_MARKERS = "sD^v<>ph*"


def plot_scene(res, folder):
    """Log-log error vs run time, one line per method (rtol points joined in order)."""
    case = res["case"]
    groups = {}
    for r in res["rows"]:
        if r["status"] != "ok" or not np.isfinite(r["error"]) or not np.isfinite(r["time"]):
            continue
        groups.setdefault((r["family"], _method(r)), []).append(r)
    fig, ax = plt.subplots(figsize=(10, 6))
    regs = sorted({r["regularisation"] for r in res["rows"] if r["regularisation"]})
    nj_index = 0
    for (family, label), pts in sorted(groups.items(), key=lambda kv: _FAMILY_ORDER[kv[0][0]]):
        pts = sorted(pts, key=lambda r: -r["rtol"])
        style = dict(_FAMILY_STYLE[family])
        if family == "nivpjax":
            style["color"] = _NJ_COLORS[nj_index % len(_NJ_COLORS)]
            marker = "o"
            nj_index += 1
        elif family in ("diffrax", "scipy"):
            style["color"] = _OTHER_COLORS.get(pts[0]["method"], "grey")
            marker = _MARKERS[regs.index(pts[0]["regularisation"]) % len(_MARKERS)]
        else:
            marker = "s"
        if family == "reference":
            label = "solve_nivp: " + label.split(",")[0]
        err = np.maximum([p["error"] for p in pts], 1e-16)
        ax.loglog([p["time"] for p in pts], err, marker=marker, ms=5, label=label, **style)
    ax.axhline(REG_TARGET_ERR, color="grey", lw=0.8, ls="-.")
    ax.set_xlabel("run time per trajectory after compilation [s]")
    ax.set_ylabel("error (floored at 1e-16)")
    ax.set_title(f"{case.title}\nerror: {case.norm}", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    path = os.path.join(folder, f"{case.name}.png")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def scene_table(res):
    headers = [
        "method",
        "rtol",
        "error",
        "run",
        "compile",
        "acc/rej steps",
        "Newton/VI it.",
        "status",
    ]
    rows = []
    for r in res["rows"]:
        rows.append(
            [
                _method(r),
                f"{r['rtol']:.0e}",
                fmt_num(r["error"]),
                fmt_time(r["time"]),
                fmt_time(r["compile"]) if np.isfinite(r["compile"]) else "",
                _steps(r),
                "-" if r["iterations"] is None else r["iterations"],
                r["status"],
            ]
        )
    return markdown_table(headers, rows)


def _nj_desc(nj):
    return f"{nj['method']} rtol {nj['rtol']:.0e}"


def comparison_tables(res):
    ref_rows = []
    for c in res["reference"]:
        r, nj = c["ref"], c["nj"]
        verdict = (
            c["note"]
            if c["ratio"] is None
            else ("met" if c["ratio"] >= REF_TARGET else f"MISSED (< {REF_TARGET:g}x)")
        )
        ref_rows.append(
            [
                f"{r['rtol']:.0e}",
                fmt_num(r["error"]),
                fmt_time(r["time"]),
                _steps(r),
                "-" if nj is None else _nj_desc(nj),
                "-" if nj is None else fmt_num(nj["error"]),
                "-" if nj is None else fmt_time(nj["time"]),
                _ratio(c["ratio"]),
                verdict,
            ]
        )
    ref_table = markdown_table(
        [
            "ref rtol",
            "ref error",
            "ref run",
            "ref acc/rej",
            "fastest nivpjax at <= error",
            "its error",
            "its run",
            "ref / nivpjax",
            f"target >= {REF_TARGET:g}x",
        ],
        ref_rows,
    )
    reg_rows = []
    for c in res["regularised"]:
        r, nj = c["other"], c["nj"]
        verdict = (
            "MISSED (nivpjax does not reach this error in the sweep)"
            if c["ratio"] is None
            else ("met" if c["ratio"] >= 1 else "MISSED (< 1x)")
        )
        reg_rows.append(
            [
                _method(r),
                f"{r['rtol']:.0e}",
                fmt_num(r["error"]),
                fmt_time(r["time"]),
                "-" if nj is None else _nj_desc(nj),
                "-" if nj is None else fmt_num(nj["error"]),
                "-" if nj is None else fmt_time(nj["time"]),
                _ratio(c["ratio"]),
                verdict,
            ]
        )
    reg_table = (
        markdown_table(
            [
                "regularised solver",
                "rtol",
                "error",
                "run",
                "fastest nivpjax at <= error",
                "its error",
                "its run",
                "other / nivpjax",
                "target >= 1x",
            ],
            reg_rows,
        )
        if reg_rows
        else f"(no regularised run reaches an error below {REG_TARGET_ERR:g})"
    )
    return ref_table, reg_table


# --- verdicts ----------------------------------------------------------------------------------
def reference_verdict(res):
    """(cell, verdict, why) of the >= 30x target for one scene."""
    matched = [c for c in res["reference"] if c["ratio"] is not None]
    if not matched:
        notes = "; ".join(sorted({c["note"] for c in res["reference"]}))
        return "n/a", "not measured", notes
    worst = min(matched, key=lambda c: c["ratio"])
    cell = ", ".join(f"{_ratio(c['ratio'])} (rtol {c['ref']['rtol']:.0e})" for c in matched)
    unmatched = [c for c in res["reference"] if c["ratio"] is None]
    extra = (
        "; unmatched: " + "; ".join(f"rtol {c['ref']['rtol']:.0e}: {c['note']}" for c in unmatched)
        if unmatched
        else ""
    )
    if worst["ratio"] >= REF_TARGET:
        return cell, "met", "min " + _ratio(worst["ratio"]) + extra
    r, nj = worst["ref"], worst["nj"]
    attempts = (nj["accepted"] or 0) + (nj["rejected"] or 0)
    why = (
        f"at rtol {r['rtol']:.0e} the reference needs only {fmt_time(r['time'])} "
        f"({r['accepted']} steps); nivpjax's fastest run at <= its error "
        f"({_nj_desc(nj)}) takes {fmt_time(nj['time'])} for {attempts} attempted steps "
        f"({fmt_time(nj['time'] / max(attempts, 1))}/step)" + extra
    )
    return cell, "MISSED", why


def regularised_verdict(res):
    comps = res["regularised"]
    if not comps:
        return (
            "no regularised run below 1e-3",
            "met (vacuous)",
            f"no diffrax/scipy run reaches an error below {REG_TARGET_ERR:g} (regularisation "
            "error floor)",
        )
    unmatched = [c for c in comps if c["ratio"] is None]
    matched = [c for c in comps if c["ratio"] is not None]
    worst = min(matched, key=lambda c: c["ratio"]) if matched else None
    cell = "n/a" if worst is None else f"{_ratio(worst['ratio'])} vs {_method(worst['other'])}"
    if unmatched:
        u = min(unmatched, key=lambda c: c["other"]["error"])
        return (
            cell,
            "MISSED",
            f"{_method(u['other'])} rtol {u['other']['rtol']:.0e} reaches "
            f"{u['other']['error']:.1e}, below every nivpjax run of the sweep",
        )
    if worst["ratio"] >= 1:
        return cell, "met", f"min {_ratio(worst['ratio'])} over {len(matched)} points"
    o, nj = worst["other"], worst["nj"]
    return (
        cell,
        "MISSED",
        f"{_method(o)} rtol {o['rtol']:.0e} reaches {o['error']:.1e} in {fmt_time(o['time'])}; "
        f"nivpjax needs {fmt_time(nj['time'])} ({_nj_desc(nj)}) for <= that error",
    )


def headline_table(wp):
    rows = []
    for res in wp:
        c1, v1, w1 = reference_verdict(res)
        c2, v2, w2 = regularised_verdict(res)
        rows.append([res["case"].name, c1, v1, c2, v2])
    return markdown_table(
        [
            "scene",
            "reference / nivpjax at equal or better error",
            f">= {REF_TARGET:g}x",
            f"worst regularised / nivpjax at equal error < {REG_TARGET_ERR:g}",
            ">= 1x",
        ],
        rows,
    )


def batched_table(batched):
    rows = []
    for b in batched:
        ref = b["reference"]
        for r in b["rows"]:
            ratio = ref["per_traj"] / r["per_traj"]
            rows.append(
                [
                    b["sweep"]["case"],
                    r["n"],
                    fmt_time(r["compile"]),
                    fmt_time(r["time"]),
                    fmt_time(r["per_traj"]),
                    f"{r['traj_per_s']:.0f}",
                    f"{r['steps_per_s']:.3g}",
                    f"{r['accepted_mean']:.0f}",
                    f"{r['waste']:.0%}",
                    f"{r['xla_mb']:.1f}",
                    f"{r['rss_growth_mb']:.0f}",
                    f"{fmt_num(r['median_error'])} / {fmt_num(r['max_error'])}",
                    r["failed"],
                    fmt_time(ref["per_traj"] * r["n"]) + " (extrap.)",
                    _ratio(ratio),
                ]
            )
    return markdown_table(
        [
            "scene",
            "N",
            "compile",
            "batch run",
            "per traj",
            "traj/s",
            "acc. step-traj/s",
            "mean acc. steps",
            "waste",
            "XLA buffers MB",
            "RSS high-water growth MB",
            "final position err median / max",
            "failed",
            "reference loop x N",
            "ref / nivpjax per traj",
        ],
        rows,
    )


def reference_loop_lines(batched):
    out = []
    for b in batched:
        ref = b["reference"]
        out.append(
            f"- {b['sweep']['case']}: reference ({ref['label']}, rtol {ref['rtol']:g}) in a "
            f"Python loop over {ref['n']} of the parameter values: "
            f"{fmt_time(ref['per_traj'])} per trajectory (max final position error "
            f"{fmt_num(ref['max_error'])}"
            + (
                f"; {ref['timeouts']} run(s) stopped at the time limit, counted at the limit"
                if ref.get("timeouts")
                else ""
            )
            + "); the 'reference loop x N' column multiplies this by N (extrapolated, not run)."
        )
    return "\n".join(out)


def mitigation_table(batched):
    rows = []
    for b in batched:
        for m in b["mitigation"]:
            rows.append([m["scene"], m["strategy"], fmt_time(m["time"]), f"{m['waste']:.0%}"])
    return markdown_table(["scene", "strategy", "time (whole sweep)", "waste"], rows)


def gradient_table(grads):
    rows = []
    for g in grads:
        verdict = "met" if g["ratio"] <= GRAD_TARGET else "MISSED"
        rows.append(
            [
                g["scene"],
                g["param"],
                "-" if g.get("h_max") is None else f"{g['h_max']:g}",
                fmt_time(g["fwd_compile"]),
                fmt_time(g["vg_compile"]),
                fmt_time(g["fwd"]),
                fmt_time(g["vg"]),
                f"{g['ratio']:.2f}",
                verdict,
                f"{g['loss']:.4g} ({g['exact_loss']:.4g})",
                f"{g['grad']:.4g}",
                f"{g['exact_grad']:.4g}",
                f"{g['grad_rel_err']:.1%}",
            ]
        )
    return markdown_table(
        [
            "scene",
            "parameter",
            "h_max",
            "compile forward",
            "compile value_and_grad",
            "forward",
            "value_and_grad",
            "ratio",
            f"<= {GRAD_TARGET:g}x",
            "loss (on exact solution)",
            "gradient",
            "exact d loss",
            "rel. error",
        ],
        rows,
    )


def targets_table(wp, batched, grads, quick):
    rows = []
    # 1. reference, every scene
    v = [(res["case"].name, *reference_verdict(res)) for res in wp]
    missed = [x for x in v if x[2] != "met"]
    rows.append(
        [
            f">= {REF_TARGET:g}x faster than the reference per trajectory at equal or better "
            "error, every scene",
            "; ".join(f"{n}: {c}" for n, c, _, _ in v),
            "MET" if not missed else "MISSED",
            "all scenes met"
            if not missed
            else " / ".join(f"{n} ({s}): {w}" for n, _, s, w in missed),
        ]
    )
    # 2. batch of 10000
    cells, verdict, why = [], "MET" if batched else "NOT MEASURED", []
    for b in batched:
        ref = b["reference"]
        big = max(b["rows"], key=lambda r: r["n"])
        ratio = ref["per_traj"] / big["per_traj"]
        cells.append(f"{b['sweep']['case']} N={big['n']}: {_ratio(ratio)}")
        if big["n"] < BATCH_TARGET_N:
            verdict = "NOT MEASURED" if verdict == "MET" else verdict
            why.append(f"{b['sweep']['case']}: the run stopped at N={big['n']}")
        elif ratio < BATCH_TARGET:
            verdict = "MISSED"
            unb = next(r for r in b["rows"] if r["n"] == 1)
            why.append(
                f"{b['sweep']['case']}: {fmt_time(big['per_traj'])} per trajectory in the batch "
                f"(unbatched {fmt_time(unb['per_traj'])}, waste {big['waste']:.0%}) vs "
                f"{fmt_time(ref['per_traj'])} for the reference"
            )
    rows.append(
        [
            f">= {BATCH_TARGET:g}x per trajectory in a batch of {BATCH_TARGET_N}",
            "; ".join(cells),
            verdict,
            "; ".join(why) or ("met" if batched else "skipped"),
        ]
    )
    # 3. regularised
    v = [(res["case"].name, *regularised_verdict(res)) for res in wp]
    missed = [x for x in v if not x[2].startswith("met")]
    rows.append(
        [
            f"beats regularised diffrax/scipy at equal error below {REG_TARGET_ERR:g}, every scene",
            "; ".join(f"{n}: {c}" for n, c, _, _ in v),
            "MET" if not missed else "MISSED",
            "all scenes met" if not missed else " / ".join(f"{n}: {w}" for n, _, _, w in missed),
        ]
    )
    # 4. gradient
    bad = [g for g in grads if g["ratio"] > GRAD_TARGET]
    accuracy = "; gradient vs exact derivative: " + ", ".join(
        f"{g['scene']} {g['grad_rel_err']:.1%} off" for g in grads
    )
    rows.append(
        [
            f"gradient <= {GRAD_TARGET:g}x forward",
            "; ".join(f"{g['scene']}: {g['ratio']:.2f}x" for g in grads),
            "NOT MEASURED" if not grads else ("MET" if not bad else "MISSED"),
            (
                ("met" if grads else "skipped")
                if not bad
                else "; ".join(
                    f"{g['scene']}: value_and_grad {fmt_time(g['vg'])} vs forward "
                    f"{fmt_time(g['fwd'])}"
                    for g in bad
                )
            )
            + (accuracy if grads else ""),
        ]
    )
    return markdown_table(["target", "measured", "verdict", "why"], rows)


# --- documents -------------------------------------------------------------------------------
def _methodology(quick, batched):
    sizes = sorted({r["n"] for b in batched for r in b["rows"]})
    scenes = " and ".join(b["sweep"]["case"] for b in batched) or "no scene"
    batches = f"batches of {', '.join(map(str, sizes))} on {scenes}" if batched else "no batches"
    if quick:
        nj_set, other_set = "1e-3 ... 1e-7, one per decade", "1e-3, 1e-5"
        mode = (
            "--quick (2 tolerances, 2 nivpjax configurations (Bathe x SSN/VI), 2 "
            f"regularisation strengths, {batches}, 3 repeats)"
        )
    else:
        nj_set, other_set = "1e-2 ... 1e-8, two per decade", "1e-2 ... 1e-7, one per decade"
        mode = (
            "full (6 tolerances, 4 steppers x 2 solvers, 3 regularisation strengths, "
            f"{batches}, 7 repeats)"
        )
    return f"""\
- Work-precision: every method on each scene at rtol in the sweep, atol = 1e-3 rtol. nivpjax
  and diffrax: compiled once per configuration (tolerances, and diffrax's regularisation
  strength, are inputs of one executable; compile = `jax.jit(f).lower(...).compile()`,
  nivpjax with `nj.compiler_options()` as its own top-level programs, diffrax with XLA's
  defaults as its users get it), run = median over repeats of the mean of back-to-back
  calls of the jitted function after compilation (JAX's C++ dispatch, as users call it;
  nivpjax returns the whole `Solution`).
  Both save every step into output buffers of `max_steps` rows, which are allocated and
  filled on every call: each run uses the smallest of 1024 or 16384 rows (diffrax: 1024,
  16384 or 100000) that holds it, as a user sizes `max_steps` for the job (each size is
  compiled once; the compile column is the smallest size's). The reference package and
  scipy: same timing (a single run
  when one takes over 1 s). Errors against the exact/trusted nonsmooth reference (norm stated
  per scene below); regularised models are measured against the same nonsmooth reference, so
  their errors include the regularisation error.
- The reference package (solve_nivp 0.1.2) runs every scene: ball and slider with its
  notebook settings, relay/super-twisting/rectifier/Chua rewritten with its
  SignProjection and an algebraic multiplier (diode as a bounded relay, sat(x) as a relay
  on x - w; composite scheme + semismooth Newton, the combination that works; see
  `benchmarks/reference_models.py`).
- nivpjax runs a finer tolerance set ({nj_set}) than the others ({other_set}): its runs
  are cheap once compiled, and the finer set resolves the time nivpjax needs to reach a
  given error.
- "equal or better error": the fastest nivpjax run (any stepper x solver, any rtol of the
  sweep) whose error is <= {EQUAL_ERR_SLACK:g} x the reference's error (<= the regularised
  solver's error for the second target); measured points only, no interpolation, so a
  coarse sweep charges nivpjax a tighter tolerance than it needs. Reference points with an
  error above {REF_BROKEN:g} (qualitatively wrong trajectories) or that stopped early are
  not compared. A failed nivpjax run ends its configuration's sweep (tighter tolerances
  skipped).
- nivpjax Newton/VI it. = `Solution.n_iterations` (all stages, rejected steps included);
  reference it. = sum of its solver iterations on full-step attempts; diffrax and scipy do
  not report them. scipy does not report rejected steps.
- Mode: {mode}.
"""


def write_documents(wp, batched, grads, meta, quick):
    os.makedirs(RESULTS_DIR, exist_ok=True)
    for res in wp:
        write_csv(res, RESULTS_DIR)
        plot_scene(res, RESULTS_DIR)
    head = targets_table(wp, batched, grads, quick)
    wp_head = headline_table(wp)
    bt = batched_table(batched)
    mt = mitigation_table(batched)
    gt = gradient_table(grads)
    header = (
        f"Generated by `{meta['command']}` on {meta['date']} ({meta['machine']}); "
        f"total {meta['total']:.0f} s."
    )
    parts = [
        "# nivpjax benchmarks: what accuracy costs in time",
        "",
        "<!-- generated file: do not edit; rerun the command below -->",
        "",
        header,
        "",
        "## Targets",
        "",
        head,
        "",
        "## Work-precision: headline ratios",
        "",
        wp_head,
        "",
        "## How it is measured",
        "",
        _methodology(quick, batched),
    ]
    for res in wp:
        case = res["case"]
        ref_table, reg_table = comparison_tables(res)
        parts += [
            f"## {case.title}",
            "",
            f"Error: {case.norm}. Plot: [{case.name}.png]({case.name}.png), data: "
            f"[{case.name}.csv]({case.name}.csv). Reference package: "
            f"{_ref_label(res)}.",
            "",
            f"![{case.name}]({case.name}.png)",
            "",
            "Against the reference package:",
            "",
            ref_table,
            "",
            f"Against the regularised models (points with error < {REG_TARGET_ERR:g}):",
            "",
            reg_table,
            "",
            "<details><summary>All runs</summary>",
            "",
            scene_table(res),
            "",
            "</details>",
            "",
        ]
    parts += [
        "## Batched sweeps on CPU (jax.vmap of a whole adaptive solve)",
        "",
        "Bathe + semismooth Newton, PID rtol 1e-3 (atol 1e-6), max_steps 1024, parameters "
        "uniform at random (fixed seed). XLA buffers = argument + output + temporary bytes "
        "of the compiled executable (`memory_analysis()`); RSS high-water growth = growth "
        "of `ru_maxrss` over compile + runs (0 when the process was already that large). "
        "waste = sum over members of (max attempts - own attempts) / (N x max attempts): "
        "the share of the batch's loop iterations in which a member has already finished "
        "(nivpjax does nothing about it by itself: a finished member still runs the masked "
        "loop body, so a batch costs N x the slowest member's attempts). final position err: "
        "|position(t1) - exact| per member (the position only: the velocity jumps at "
        "impacts, and a member whose impact falls within the controller's tolerance of t1 "
        "would report the jump).",
        "",
        bt,
        "",
        reference_loop_lines(batched),
        "",
        "Waste mitigation (measured): the largest batch in chunks of 100 with one compiled "
        "executable, random order vs sorted by the parameter.",
        "",
        mt,
        "",
        "## Gradients",
        "",
        "`jax.value_and_grad` of a trajectory-calibration loss (mean squared position error "
        "on a fixed output grid) vs the forward solve alone; Bathe + SSN, rtol 1e-5, "
        "checkpointed adjoint. 'exact d loss' = derivative of the same loss on the exact "
        "solution (central difference of the closed form).",
        "",
        gt,
        "",
        "Reading the gradient error: reverse mode returns the exact derivative of the "
        "discrete solution (it agrees with central differences of the compiled solve at "
        "small steps), but step sizes are not differentiated (`stop_gradient` in the "
        "controller), so the derivative misses how impact and stick times move with the "
        "parameter; it does not converge to the true derivative as rtol -> 0. For the ball "
        "the loss itself also differs from the exact loss: `t_eval` interpolates linearly "
        "over the long free-flight steps (Bathe integrates parabolas exactly, so its error "
        "estimate lets steps grow).",
        "",
    ]
    text = "\n".join(parts)
    with open(os.path.join(RESULTS_DIR, "README.md"), "w") as fh:
        fh.write(text)
    docs = "\n".join(
        [
            "# Benchmarks (generated)",
            "",
            "<!-- generated by `python -m benchmarks`: do not edit by hand -->",
            "",
            header + " Full tables, plots and CSVs: "
            "[benchmarks/results/README.md](../benchmarks/results/README.md) (committed with "
            "this page; regenerate both with the same command).",
            "",
            "## Targets",
            "",
            head,
            "",
            "## Work-precision headline",
            "",
            wp_head,
            "",
            "## Batched sweeps",
            "",
            bt,
            "",
            "## Gradients",
            "",
            gt,
            "",
        ]
    )
    with open(DOCS_FILE, "w") as fh:
        fh.write(docs)
    return dict(targets=head, headline=wp_head, batched=bt, mitigation=mt, gradients=gt)


def _ref_label(res):
    labels = {r["method"] for r in res["rows"] if r["family"] == "reference"}
    return ", ".join(sorted(labels)) or "n/a"
