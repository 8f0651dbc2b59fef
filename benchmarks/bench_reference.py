"""Whole trajectories: nivpjax's `nj.solve` against the reference `solve_nivp.solve_ivp_ns`.

Three problems with exact solutions, each at rtol = 1e-3, 1e-4, 1e-5 (atol = 1e-3 rtol for
both packages), like-for-like pairs of scheme and nonlinear solver where the reference has
a working setting:

- bouncing ball, y = [v, s], s'' = -9.81, restitution e = 0.8, y0 = [1, 2], T = 3.
  Error: max-norm of the final state vs the piecewise-ballistic solution. Reference settings
  of its notebook (trapezoidal, unilateral/GeneralMoreau, VI tol 1e-7, h0 1e-3, h_down 0.5,
  h_up 1.5, use_PI False, method_order 1); its SSN variant (rhs_jac, lam 0.2, line search)
  stops silently at the second impact and is only reported below the table. Its backward
  Euler and composite schemes do not rebound at impacts (notes §5b), so nivpjax's Bathe
  scheme is compared with the reference's trapezoidal rule.
- spring-slider with Coulomb friction, y = [v, s], A = diag(2, 1),
  2 v' = -s - 2 v - 0.6 Sign(v), v0 = 0.1, T = 1 (slides, sticks at t* = 0.30 for good).
  Error: max-norm of the final state; also the stick-time error = first accepted time with
  v = 0 minus t* (resolved only to the step size). Reference: composite (TR-BDF2) with its
  Coulomb projection, VI (notebook) or SSN, tol 1e-10, rhs_jac, h0 0.01.
- relay x' = -Sign(x) + 0.5 sin(2 pi t), x0 = 0.5, T = 2, as y = [x, w], A = diag(1, 0)
  (nivpjax: Box(-1, 1) on the algebraic multiplier w with row f_w = x; reference:
  SignProjection, which only works with SSN). Both with h_max = 0.05 (in sliding the error
  estimate is ~0 and steps would grow without bound). Error: max over accepted steps of
  |x - x_exact| and, on steps lying entirely in sliding, |w - d(t)|; also the reaching-time
  error = first accepted time with x = 0 minus the exact reaching time.

nivpjax timings: compile = first call minus a second call; run = median of 5 repeats
(after compilation) of (i) the plain public call `nj.solve(...)` (its host-side validation
included) and (ii) a `jax.jit`-wrapped call with y0 and the tolerances as arguments. The
tolerances are passed as arrays, so one compilation serves the whole sweep (compile time is
reported on each configuration's first row). Reference: median of 3 runs (1 run if a run
takes over 1 s). Ratios are reference / nivpjax per trajectory. Targets: >= 30x at equal or
better error, compile < 10 s.

Run from the repository root (about 1.5 minutes on a busy 2-core machine):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_reference

Prints a markdown table and writes it to benchmarks/results/reference.md.
"""

import contextlib
import io
import os
import platform
import time
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
import solve_nivp

import nivpjax as nj

from ._common import (
    G,
    ball_exact,
    block,
    fmt_num,
    fmt_time,
    markdown_table,
    median_time,
    relay_d,
    relay_exact,
    relay_reaching_time,
    slider_exact,
    time_once,
)


RTOLS = (1e-3, 1e-4, 1e-5)
ERR_SLACK = 0.1  # "equal or better error": err <= 1.1 * reference error
REF_BROKEN = 0.1  # a reference error above this is a qualitatively wrong trajectory
ATOL_FACTOR = 1e-3
RESULTS_DIR = os.path.join(os.path.dirname(__file__), "results")

# --- problems: nivpjax side ----------------------------------------------------------------------
E_BALL, T_BALL, Y0_BALL = 0.8, 3.0, (1.0, 2.0)
BALL_PROJ = nj.UnilateralContact(
    gap=lambda t, y, a: y[1:2],
    velocity_map=lambda t, y, a: jnp.array([[1.0, 0.0]], y.dtype),
    restitution=E_BALL,
)


def ball_field(t, y, a):
    return jnp.stack([-G * jnp.ones_like(y[0]), y[0]])


MASS, K_SPRING, C_DAMP, FRIC, T_SLIDER, Y0_SLIDER = 2.0, 1.0, 2.0, 0.6, 1.0, (0.1, 0.0)
SLIDER_PROJ = nj.BlockProjector([([0], nj.CoulombFriction(FRIC))])
SLIDER_A = np.diag([MASS, 1.0])


def slider_field(t, y, a):
    return jnp.stack([-K_SPRING * y[1] - C_DAMP * y[0], y[0]])


T_RELAY, Y0_RELAY, H_MAX_RELAY = 2.0, (0.5, 1.0), 0.05
RELAY_PROJ = nj.BlockProjector([([1], nj.Box(-1.0, 1.0))])
RELAY_A = np.diag([1.0, 0.0])


def relay_field(t, y, a):
    return jnp.stack([-y[1] + 0.5 * jnp.sin(2 * jnp.pi * t), y[0]])


NJ_PROBLEMS = {
    "ball": dict(f=ball_field, t1=T_BALL, y0=Y0_BALL, projector=BALL_PROJ, mass=None, ctrl={}),
    "slider": dict(
        f=slider_field, t1=T_SLIDER, y0=Y0_SLIDER, projector=SLIDER_PROJ, mass=SLIDER_A, ctrl={}
    ),
    "relay": dict(
        f=relay_field,
        t1=T_RELAY,
        y0=Y0_RELAY,
        projector=RELAY_PROJ,
        mass=RELAY_A,
        ctrl=dict(h_max=H_MAX_RELAY),
    ),
}


# --- problems: reference side --------------------------------------------------------------------
def _ref_ball(solver, xp=np):
    """The reference's notebook settings for the ball; `xp=jnp` gives the same script for
    the compat entry point (its callbacks are traced by JAX)."""
    popts = dict(
        gap=lambda t, y: xp.array([y[1]]),
        u_map=lambda t, y: xp.array([y[0]]),
        J_u=lambda t, y: xp.array([[1.0, 0.0]]),
        G_apply=lambda t, y, lam: xp.array([lam[0], 0.0]),
        e=E_BALL,
        gap_tol=0.0,
        lcp_maxit=200,
        lcp_tol=1e-10,
        tc_tol=1e-10,
    )
    sopts = dict(tol=1e-7, max_iter=200)
    if solver == "semismooth_newton":
        sopts.update(
            rhs_jac=lambda t, y: xp.array([[0.0, 0.0], [1.0, 0.0]]),
            lam=0.2,
            globalization="linesearch",
            max_backtracks=25,
            ls_min_alpha=1e-10,
        )
    return dict(
        fun=lambda t, y: xp.array([-G, y[0]]),
        t_span=(0.0, T_BALL),
        y0=np.array(Y0_BALL),
        method="trapezoidal",
        projection="unilateral",
        solver=solver,
        projection_opts=popts,
        solver_opts=sopts,
        adaptive_opts=dict(
            h0=1e-3, h_min=1e-12, h_down=0.5, h_up=1.5, method_order=1, use_PI=False
        ),
        h0=1e-3,
        component_slices=[slice(0, 1), slice(1, 2)],
    )


def _ref_slider(solver, xp=np):
    """The reference's notebook settings for the slider (`xp` as for `_ref_ball`)."""
    cs = [slice(0, 1), slice(1, 2)]

    def con_force(y, t=None, Fk_val=None):
        # zero on unconstrained entries (the reference acts wherever c != 0)
        return xp.array([FRIC, 0.0])

    return dict(
        fun=lambda t, y: xp.array([-K_SPRING * y[1] - C_DAMP * y[0], y[0]]),
        t_span=(0.0, T_SLIDER),
        y0=np.array(Y0_SLIDER),
        method="composite",
        projection="coulomb",
        solver=solver,
        projection_opts=dict(
            con_force_func=con_force,
            rhok=np.ones(2),
            component_slices=cs,
            constraint_indices=[0],
            jac_func=lambda y, t=None, Fk_val=None: xp.zeros((2, 2)),
        ),
        solver_opts=dict(
            tol=1e-10,
            max_iter=100,
            rhs_jac=lambda t, y: xp.array([[-C_DAMP, -K_SPRING], [1.0, 0.0]]),
        ),
        h0=0.01,
        component_slices=cs,
        A=SLIDER_A,
    )


def _ref_relay(method):
    return dict(
        fun=lambda t, y: np.array([-y[1] + relay_d(t), 0.0]),
        t_span=(0.0, T_RELAY),
        y0=np.array(Y0_RELAY),
        method=method,
        projection="sign",
        solver="semismooth_newton",
        projection_opts=dict(y_indices=[0], w_indices=[1]),
        solver_opts=dict(
            tol=1e-10, max_iter=100, rhs_jac=lambda t, y: np.array([[0.0, -1.0], [0.0, 0.0]])
        ),
        adaptive_opts=dict(h_min=1e-8, h_max=H_MAX_RELAY, skip_error_indices=[1]),
        h0=1e-2,
        component_slices=[slice(0, 1), slice(1, 2)],
        A=RELAY_A,
    )


# --- errors ------------------------------------------------------------------------------------
def errors(problem, t, y):
    """(error, second metric, text of the second metric) of a trajectory (accepted points)."""
    t, y = np.asarray(t), np.asarray(y)
    if problem == "ball":
        if t[-1] < T_BALL - 1e-9:
            return float("inf"), None, f"stopped at t={t[-1]:.3f}"
        exact, _ = ball_exact(T_BALL, *Y0_BALL, e=E_BALL)
        return float(np.max(np.abs(y[-1] - exact))), None, ""
    if problem == "slider":
        t_stick, s_stick = slider_exact(MASS, K_SPRING, C_DAMP, FRIC, Y0_SLIDER[0])
        err = float(np.max(np.abs(y[-1] - [0.0, s_stick])))
        stuck = np.flatnonzero(np.abs(y[:, 0]) <= 1e-9)
        if stuck.size == 0:
            return err, None, "never sticks"
        dt = float(t[stuck[0]] - t_stick)
        return err, dt, f"t_stick {dt:+.1e}"
    # relay
    t_reach = relay_reaching_time(Y0_RELAY[0])
    x_ex, w_ex = relay_exact(t, Y0_RELAY[0])
    err_x = np.max(np.abs(y[:, 0] - x_ex))
    sliding = np.r_[False, t[:-1] >= t_reach]
    err_w = np.max(np.abs(y[sliding, 1] - w_ex[sliding]), initial=0.0)
    on = np.flatnonzero(np.abs(y[:, 0]) <= 1e-9)
    dt = float(t[on[0]] - t_reach) if on.size else float("nan")
    return float(max(err_x, err_w)), dt, f"t_reach {dt:+.1e}"


# --- runners -------------------------------------------------------------------------------------
@dataclass
class NjConfig:
    problem: str
    label: str
    stepper: nj.AbstractStepper
    results: dict = field(default_factory=dict)


def _nj_call(problem, stepper, y0, rtol, atol):
    p = NJ_PROBLEMS[problem]
    ctrl = nj.PIDController(rtol=rtol, atol=atol, **p["ctrl"])
    return nj.solve(
        p["f"],
        0.0,
        p["t1"],
        y0,
        projector=p["projector"],
        mass_matrix=p["mass"],
        stepper=stepper,
        controller=ctrl,
    )


def run_nivpjax(cfg: NjConfig):
    p = NJ_PROBLEMS[cfg.problem]
    y0 = jnp.asarray(p["y0"], jnp.float64)
    plain = lambda y0, rtol, atol: _nj_call(cfg.problem, cfg.stepper, y0, rtol, atol)
    jitted = jax.jit(plain)
    compile_plain = compile_jit = None
    for rtol in RTOLS:
        tol = (jnp.asarray(rtol), jnp.asarray(rtol * ATOL_FACTOR))
        if compile_plain is None:
            first, _ = time_once(plain, y0, *tol)
            second, _ = time_once(plain, y0, *tol)
            compile_plain = first - second
            first, _ = time_once(jitted, y0, *tol)
            second, _ = time_once(jitted, y0, *tol)
            compile_jit = first - second
        t_plain, sol = median_time(plain, y0, *tol, repeats=5, number=3)
        t_jit, _ = median_time(jitted, y0, *tol, repeats=5, number=5)
        sol = sol.trimmed()
        err, err2, err2_text = errors(cfg.problem, sol.ts, sol.ys)
        cfg.results[rtol] = dict(
            compile_plain=compile_plain,
            compile_jit=compile_jit,
            t_plain=t_plain,
            t_jit=t_jit,
            accepted=int(sol.n_accepted),
            rejected=int(sol.n_rejected),
            err=err,
            err2=err2,
            err2_text=err2_text,
        )
        compile_plain = compile_jit = 0.0  # compiled once for the whole tolerance sweep


def run_reference(kwargs, rtol):
    kwargs = dict(kwargs, rtol=rtol, atol=rtol * ATOL_FACTOR, return_attempts=True)

    def once():
        with contextlib.redirect_stdout(io.StringIO()):  # the reference prints on some paths
            return solve_nivp.solve_ivp_ns(**kwargs)

    try:
        first, out = time_once(once)
        times = [first]
        if first < 1.0:
            for _ in range(2):
                dt, out = time_once(once)
                times.append(dt)
    except Exception as err:
        return dict(time=None, accepted=None, rejected=None, exc=f"{type(err).__name__}: {err}")
    t, y, *_, attempts = out
    rejected = int(np.sum(~np.asarray(attempts["accepted"], bool))) if attempts else None
    return dict(
        time=float(np.median(times)),
        accepted=len(t) - 1,
        rejected=rejected,
        t=np.asarray(t),
        y=np.asarray(y, float),
    )


# --- main --------------------------------------------------------------------------------------
def main():
    t_start = time.perf_counter()
    vi = lambda tol: nj.FixedPointVI(rtol=tol, atol=tol)
    configs = [
        # (nivpjax config, reference label, reference kwargs)
        (
            NjConfig("ball", "Trapezoidal + FixedPointVI(1e-7)", nj.Trapezoidal(solver=vi(1e-7))),
            "trapezoidal + VI",
            _ref_ball("VI"),
        ),
        (
            NjConfig("ball", "Bathe + SemismoothNewton (default)", nj.Bathe()),
            "trapezoidal + VI",
            _ref_ball("VI"),
        ),
        (
            NjConfig("slider", "Bathe + FixedPointVI(1e-10)", nj.Bathe(solver=vi(1e-10))),
            "composite + VI",
            _ref_slider("VI"),
        ),
        (
            NjConfig("slider", "Bathe + SemismoothNewton", nj.Bathe()),
            "composite + SSN",
            _ref_slider("semismooth_newton"),
        ),
        (
            NjConfig("relay", "BackwardEuler + SemismoothNewton", nj.BackwardEuler()),
            "backward_euler + SSN",
            _ref_relay("backward_euler"),
        ),
        (
            NjConfig("relay", "Bathe + SemismoothNewton", nj.Bathe()),
            "composite + SSN",
            _ref_relay("composite"),
        ),
    ]

    ref_cache = {}
    rows = []
    for cfg, ref_label, ref_kwargs in configs:
        run_nivpjax(cfg)
        for rtol in RTOLS:
            key = (cfg.problem, ref_label, rtol)
            if key not in ref_cache:
                ref_cache[key] = run_reference(ref_kwargs, rtol)
            ref = ref_cache[key]
            r = cfg.results[rtol]
            if ref["time"] is None:
                ref_err = (float("inf"), None, ref["exc"][:60])
            else:
                ref_err = errors(cfg.problem, ref["t"], ref["y"])
            ratio_plain = ref["time"] / r["t_plain"] if ref["time"] else None
            ratio_jit = ref["time"] / r["t_jit"] if ref["time"] else None
            err_ratio = r["err"] / ref_err[0] if ref_err[0] > 0 else float("inf")
            better = err_ratio <= 1 + ERR_SLACK
            fast = ratio_plain is not None and ratio_plain >= 30
            if not (ref_err[0] <= REF_BROKEN):
                target = "n/a (ref wrong)"
            elif better and fast:
                target = "met"
            else:
                target = (
                    "MISSED ("
                    + " & ".join(
                        w for w, bad in (("speed", not fast), ("error", not better)) if bad
                    )
                    + ")"
                )
            first_row = rtol == RTOLS[0]
            rows.append(
                [
                    cfg.problem if first_row else "",
                    f"{rtol:.0e}",
                    cfg.label,
                    fmt_time(r["compile_plain"]) if first_row else "",
                    fmt_time(r["compile_jit"]) if first_row else "",
                    fmt_time(r["t_plain"]),
                    fmt_time(r["t_jit"]),
                    f"{r['accepted']}/{r['rejected']}",
                    fmt_num(r["err"]) + (f" ({r['err2_text']})" if r["err2_text"] else ""),
                    ref_label,
                    fmt_time(ref["time"]),
                    "n/a" if ref["accepted"] is None else f"{ref['accepted']}/{ref['rejected']}",
                    fmt_num(ref_err[0]) + (f" ({ref_err[2]})" if ref_err[2] else ""),
                    "n/a" if ratio_plain is None else f"{ratio_plain:.0f}x",
                    "n/a" if ratio_jit is None else f"{ratio_jit:.0f}x",
                    fmt_num(err_ratio, ".2f"),
                    target,
                ]
            )

    # The reference's semismooth Newton on the ball (notebook SSN options), once: it stops early.
    ssn = run_reference(_ref_ball("semismooth_newton"), RTOLS[0])
    ssn_line = (
        f"Reference trapezoidal + SSN on the ball (rtol {RTOLS[0]:g}): "
        + (
            f"raised {ssn['exc']}"
            if ssn["time"] is None
            else f"{fmt_time(ssn['time'])}, {ssn['accepted']}/{ssn['rejected']} steps, "
            f"ends at t = {ssn['t'][-1]:.4f} of {T_BALL} (silent h_min stop)"
        )
        + "; not used in the table."
    )

    headers = [
        "problem",
        "rtol",
        "nivpjax stepper + solver",
        "compile (nj.solve)",
        "compile (jit)",
        "run nj.solve",
        "run jit",
        "acc/rej",
        "error",
        "reference",
        "ref run",
        "ref acc/rej",
        "ref error",
        "ref/nj (nj.solve)",
        "ref/nj (jit)",
        "err / ref err",
        "target",
    ]
    table = markdown_table(headers, rows)
    notes = (
        f"atol = {ATOL_FACTOR:g} * rtol for both packages. error: ball = max-norm of the "
        "final-state error at T=3; slider = max-norm of the final-state error (t_stick: first "
        "accepted time with v=0 minus the exact stick time, limited by the step size); relay "
        "= max over accepted steps of |x - x_exact| and of |w - d(t)| on steps entirely in "
        "sliding (t_reach: first accepted time with x=0 minus the exact reaching time). "
        "acc/rej = accepted/rejected steps. compile = first call minus second call, once per "
        "configuration (the tolerances are arrays, so the sweep reuses it). run nj.solve = "
        "the plain public call; run jit = the same call inside jax.jit (y0 and tolerances as "
        "arguments). target: met = ref/nj (nj.solve) >= 30 and error <= "
        f"{1 + ERR_SLACK:g} x the reference's error at the same tolerance; 'n/a (ref wrong)' "
        f"= the reference's error exceeds {REF_BROKEN:g} (wrong trajectory), so no speed "
        "comparison at equal error exists."
    )
    header = (
        "# nivpjax vs solve_nivp 0.1.2: whole trajectories\n\n"
        f"{time.strftime('%Y-%m-%d %H:%M')}, {platform.machine()}, "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}, jax {jax.__version__}, "
        f"backend {jax.default_backend()}, float64.\n"
    )
    out = f"{header}\n{table}\n\n{notes}\n\n{ssn_line}\n"
    print(out)
    os.makedirs(RESULTS_DIR, exist_ok=True)
    with open(os.path.join(RESULTS_DIR, "reference.md"), "w") as fh:
        fh.write(out)
    print(
        f"(written to benchmarks/results/reference.md; total {time.perf_counter() - t_start:.0f} s)"
    )


if __name__ == "__main__":
    block(jnp.zeros(()))  # start the backend outside the first compile measurement
    main()
