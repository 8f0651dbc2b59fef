"""Work-precision sweeps: nivpjax, the reference package and regularised diffrax/scipy on
the scenes of `cases.py`, each against the exact nonsmooth reference.

Timings: nivpjax and diffrax are compiled once per configuration (`jax.jit(...).lower(...)
.compile()`, reported as compile time; the tolerances, and for diffrax the regularisation
strength, are inputs of the executable), then the run time is the median over repeats of
the mean of back-to-back calls (outputs blocked on). The nivpjax call returns the whole
`Solution`. The reference and scipy are timed the same way (one run if it takes over 1 s).
atol = 1e-3 rtol for every method.
"""

import time

import jax.numpy as jnp
import numpy as np

import nivpjax as nj

from . import reference_models, regularised
from ._common import (
    BufferTiers,
    TimeLimit,
    auto_number,
    median_time,
    time_limit,
)
from .cases import CASES


ATOL_FACTOR = 1e-3
NJ_TIERS = (1024, 16384)  # output-buffer sizes (max_steps), see `BufferTiers`
# nivpjax's own top-level programs compile with these (see `nj.compiler_options`).
NJ_OPTIONS = nj.compiler_options()
EQUAL_ERR_SLACK = 1.1  # nivpjax "equal or better" error: err <= 1.1 x the other's error
REF_BROKEN = 0.5  # a reference error above this is a qualitatively wrong trajectory
REG_TARGET_ERR = 1e-3  # the regularised-solver target applies below this error

STEPPERS = {
    "Bathe": nj.Bathe,
    "Trapezoidal": nj.Trapezoidal,
    "BackwardEuler": nj.BackwardEuler,
    "EmbeddedBETR": nj.EmbeddedBETR,
    "EventDriven": nj.EventDriven,
}
# Scenes whose laws the event-driven stepper freezes (on algebraic rows only; it refuses
# friction on a velocity and contacts with impacts before any work).
EVENT_DRIVEN_SCENES = ("relay", "super_twisting", "rectifier", "chua")
SOLVERS = {"SSN": nj.SemismoothNewton, "VI": nj.FixedPointVI}


def settings(quick):
    if quick:
        return dict(
            rtols=(1e-3, 1e-5),
            nj_rtols=(1e-3, 1e-4, 1e-5, 1e-6, 1e-7),
            nj_configs=[("Bathe", "SSN"), ("Bathe", "VI"), ("EventDriven", "SSN")],
            diffrax=("Kvaerno5", "Tsit5"),
            scipy=("BDF", "Radau"),
            strengths=lambda name: regularised.STRENGTHS[name][::2],
            repeats=3,
            slow_skip=15.0,
            run_limit=30.0,
        )
    return dict(
        rtols=(1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7),
        nj_rtols=tuple(float(f"{x:.0e}") for x in np.logspace(-2, -8, 13)),
        # The event-driven stepper's solver only solves the initial state: one config.
        nj_configs=[(s, v) for s in STEPPERS if s != "EventDriven" for v in SOLVERS]
        + [("EventDriven", "SSN")],
        diffrax=("Kvaerno5", "Tsit5"),
        scipy=("BDF", "Radau"),
        strengths=lambda name: regularised.STRENGTHS[name],
        repeats=7,
        slow_skip=30.0,
        run_limit=90.0,
    )


def _row(case, family, method, reg, rtol, **kw):
    row = dict(
        scene=case.name,
        family=family,
        method=method,
        regularisation=reg,
        rtol=rtol,
        atol=rtol * ATOL_FACTOR,
        error=np.nan,
        time=np.nan,
        compile=np.nan,
        accepted=None,
        rejected=None,
        iterations=None,
        rhs_evals=None,
        status="ok",
    )
    row.update(kw)
    return row


# --- nivpjax ---------------------------------------------------------------------------------
def nivpjax_rows(case, configs, rtols, repeats, log):
    scene, x0, args = case.make()
    rows = []
    for stepper_name, solver_name in configs:
        if stepper_name == "EventDriven" and case.name not in EVENT_DRIVEN_SCENES:
            continue
        stepper = STEPPERS[stepper_name](solver=SOLVERS[solver_name]())
        label = f"{stepper_name} + {solver_name}"

        def build(max_steps, stepper=stepper):
            def solve(rtol, atol, x0, args):
                controller = nj.PIDController(rtol=rtol, atol=atol, h_max=case.h_max)
                return scene.solve(
                    0.0,
                    case.t1,
                    x0,
                    args,
                    stepper=stepper,
                    controller=controller,
                    max_steps=max_steps,
                    throw=False,
                )

            return solve

        tol = lambda r: (jnp.asarray(r), jnp.asarray(r * ATOL_FACTOR))
        tiers = BufferTiers(
            build, NJ_TIERS, _nj_overflowed, *tol(rtols[0]), x0, args, options=NJ_OPTIONS
        )
        for i, rtol in enumerate(rtols):
            inputs = (*tol(rtol), x0, args)
            compiled, sol, once = tiers(*inputs)
            compile_s = tiers.compile_s
            common = dict(compile=compile_s if i == 0 else np.nan)
            if sol.result != nj.RESULTS.successful:
                rows.append(
                    _row(
                        case,
                        "nivpjax",
                        label,
                        "",
                        rtol,
                        time=once,
                        accepted=int(sol.n_accepted),
                        rejected=int(sol.n_rejected),
                        iterations=int(sol.n_iterations),
                        status=f"FAILED at t={float(sol.t_final):.4g}: {nj.RESULTS[sol.result]}",
                        **common,
                    )
                )
                log(f"  {label} rtol {rtol:.0e}: FAILED ({once:.2f} s); tighter rtols skipped")
                break
            number = auto_number(compiled, *inputs)
            t_run, sol = median_time(compiled, *inputs, repeats=repeats, number=number)
            s = sol.trimmed()
            xs, _ = scene.split(s.ys)
            rows.append(
                _row(
                    case,
                    "nivpjax",
                    label,
                    "",
                    rtol,
                    time=t_run,
                    accepted=int(sol.n_accepted),
                    rejected=int(sol.n_rejected),
                    iterations=int(sol.n_iterations),
                    ts=np.asarray(s.ts),
                    xs=np.asarray(xs),
                    **common,
                )
            )
            log(
                f"  {label} rtol {rtol:.0e}: {t_run * 1e3:.2f} ms, "
                f"{int(sol.n_accepted)}/{int(sol.n_rejected)} steps"
                + (f" (compile {compile_s:.1f} s)" if i == 0 else "")
            )
    return rows


def _nj_overflowed(sol):
    return bool(sol.result == nj.RESULTS.time_max_steps_reached)


# --- the reference package -------------------------------------------------------------------
def reference_rows(case, rtols, repeats, slow_skip, run_limit, log):
    _, x0, p = case.build()
    rows = []
    builder = reference_models.BUILDERS[case.name]
    extra = dict(h_max=case.h_max) if case.h_max is not None else {}
    for rtol in rtols:
        kw, to_x, label = builder(p, x0, case.t1, rtol, rtol * ATOL_FACTOR, **extra)
        t0 = time.perf_counter()
        try:
            with time_limit(run_limit):
                out = reference_models.run(kw)
        except TimeLimit:
            rows.append(
                _row(
                    case,
                    "reference",
                    label,
                    "",
                    rtol,
                    time=time.perf_counter() - t0,
                    status=f"TIMEOUT: stopped after {run_limit:g} s",
                )
            )
            log(
                f"  reference rtol {rtol:.0e}: over {run_limit:g} s, stopped; tighter rtols skipped"
            )
            break
        except Exception as err:  # the reference's failure is a result here
            rows.append(
                _row(
                    case,
                    "reference",
                    label,
                    "",
                    rtol,
                    time=time.perf_counter() - t0,
                    status=f"FAILED: {type(err).__name__}: {str(err)[:60]}",
                )
            )
            log(f"  reference rtol {rtol:.0e}: raised {type(err).__name__}")
            continue
        once = time.perf_counter() - t0
        if once < 1.0 and repeats > 1:
            once, out = median_time(lambda: reference_models.run(kw), repeats=repeats)
        t, y, acc, rej, iters = out
        status = "ok" if t[-1] >= case.t1 - 1e-9 else f"stopped at t={t[-1]:.4g} (silent)"
        rows.append(
            _row(
                case,
                "reference",
                label,
                "",
                rtol,
                time=once,
                accepted=acc,
                rejected=rej,
                iterations=iters,
                ts=t,
                xs=to_x(y),
                status=status,
            )
        )
        log(f"  reference rtol {rtol:.0e}: {once:.3f} s, {acc}/{rej} steps")
        if once > slow_skip:
            log(f"  reference: {once:.0f} s > {slow_skip:.0f} s, tighter rtols skipped")
            break
    return rows


# --- regularised -----------------------------------------------------------------------------
def diffrax_rows(case, solvers, strengths, rtols, repeats, log):
    _, x0, _ = case.build()
    rows = []
    for name in solvers:
        a0 = (jnp.asarray(rtols[0]), jnp.asarray(rtols[0] * ATOL_FACTOR), jnp.asarray(1.0))
        tiers = BufferTiers(
            lambda max_steps, name=name: regularised.make_diffrax(case, name, max_steps),
            regularised.DIFFRAX_TIERS,
            regularised.diffrax_overflowed,
            *a0,
            jnp.asarray(x0),
        )
        first = True
        for reg in strengths:
            for rtol in rtols:
                r = regularised.run_diffrax(tiers, x0, rtol, rtol * ATOL_FACTOR, reg, repeats)
                compile_s = tiers.compile_s
                rows.append(
                    _row(
                        case,
                        "diffrax",
                        f"diffrax {name}",
                        regularised.reg_label(case.name, reg),
                        rtol,
                        compile=compile_s if first else np.nan,
                        **r,
                    )
                )
                first = False
                log(
                    f"  diffrax {name} {regularised.reg_label(case.name, reg)} rtol {rtol:.0e}: "
                    f"{r['time'] * 1e3:.2f} ms, {r['accepted']} steps, {r['status']}"
                )
    return rows


def scipy_rows(case, methods, strengths, rtols, repeats, slow_skip, run_limit, log):
    _, x0, _ = case.build()
    rows = []
    for method in methods:
        for reg in strengths:
            for rtol in rtols:
                label = regularised.reg_label(case.name, reg)
                try:
                    with time_limit(run_limit):
                        r = regularised.run_scipy(
                            case, x0, method, rtol, rtol * ATOL_FACTOR, reg, repeats
                        )
                except TimeLimit:
                    rows.append(
                        _row(
                            case,
                            "scipy",
                            f"scipy {method}",
                            label,
                            rtol,
                            time=run_limit,
                            status=f"TIMEOUT: stopped after {run_limit:g} s",
                        )
                    )
                    log(f"  scipy {method} {label} rtol {rtol:.0e}: over {run_limit:g} s, stopped")
                    break
                rows.append(_row(case, "scipy", f"scipy {method}", label, rtol, **r))
                log(
                    f"  scipy {method} {label} rtol {rtol:.0e}: {r['time'] * 1e3:.1f} ms, "
                    f"{r['accepted']} steps, {r['status']}"
                )
                if r["time"] > slow_skip:
                    log(f"  scipy {method} {label}: slow, tighter rtols skipped")
                    break
    return rows


# --- errors and ratios -----------------------------------------------------------------------
def compute_errors(case, rows):
    """Fill `error` of every row that has a trajectory, against the exact solution (one
    evaluation of the reference on the union of all output times)."""
    with_traj = [r for r in rows if "ts" in r]
    if case.final_only:
        exact = case.exact(np.array([case.t1]))[0]
        for r in with_traj:
            done = r["ts"][-1] >= case.t1 - 1e-9
            r["error"] = float(np.max(np.abs(r["xs"][-1] - exact))) if done else np.inf
    else:
        grid = np.unique(np.concatenate([r["ts"] for r in with_traj]))
        exact = case.exact(grid)
        for r in with_traj:
            idx = np.searchsorted(grid, r["ts"])
            err = np.max(np.abs(r["xs"] - exact[idx]))
            r["error"] = float(err) if np.isfinite(err) else np.inf
    for r in rows:
        r.pop("ts", None)
        r.pop("xs", None)


def _valid(r):
    return r["status"] == "ok" and np.isfinite(r["error"]) and np.isfinite(r["time"])


def _best_nivpjax(rows, max_error):
    """The fastest nivpjax row with error <= max_error, or None."""
    ok = [r for r in rows if r["family"] == "nivpjax" and _valid(r) and r["error"] <= max_error]
    return min(ok, key=lambda r: r["time"]) if ok else None


def reference_comparison(rows):
    """For every reference point: the fastest nivpjax run at equal or better error and the
    time ratio. Returns a list of dicts."""
    out = []
    for r in rows:
        if r["family"] != "reference":
            continue
        item = dict(ref=r, nj=None, ratio=None, note="")
        if not _valid(r):
            item["note"] = f"reference {r['status']}"
        elif r["error"] > REF_BROKEN:
            item["note"] = f"reference wrong (error {r['error']:.1e} > {REF_BROKEN:g})"
        else:
            best = _best_nivpjax(rows, EQUAL_ERR_SLACK * r["error"])
            if best is None:
                item["note"] = "no nivpjax run reaches this error"
            else:
                item.update(nj=best, ratio=r["time"] / best["time"])
        out.append(item)
    return out


def regularised_comparison(rows):
    """For every diffrax/scipy point with error below REG_TARGET_ERR: the fastest nivpjax
    run at equal or better error and the time ratio (competitor / nivpjax)."""
    out = []
    for r in rows:
        if r["family"] not in ("diffrax", "scipy") or not _valid(r):
            continue
        if r["error"] >= REG_TARGET_ERR:
            continue
        best = _best_nivpjax(rows, r["error"])
        out.append(
            dict(
                other=r,
                nj=best,
                ratio=None if best is None else r["time"] / best["time"],
                note="" if best is not None else "no nivpjax run reaches this error",
            )
        )
    return out


def run_scene(name, quick, log):
    case = CASES[name]
    cfg = settings(quick)
    log(f"[{name}] {case.title}")
    rows = nivpjax_rows(case, cfg["nj_configs"], cfg["nj_rtols"], cfg["repeats"], log)
    rows += reference_rows(
        case, cfg["rtols"], cfg["repeats"], cfg["slow_skip"], cfg["run_limit"], log
    )
    strengths = cfg["strengths"](name)
    rows += diffrax_rows(case, cfg["diffrax"], strengths, cfg["rtols"], cfg["repeats"], log)
    rows += scipy_rows(
        case,
        cfg["scipy"],
        strengths,
        cfg["rtols"],
        cfg["repeats"],
        cfg["slow_skip"],
        cfg["run_limit"],
        log,
    )
    compute_errors(case, rows)
    return dict(
        case=case,
        rows=rows,
        reference=reference_comparison(rows),
        regularised=regularised_comparison(rows),
    )
