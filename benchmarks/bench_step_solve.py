"""One implicit step solve: nivpjax's nonlinear solvers against the reference package.

Measures, for three single-step problems with exact solutions, each nivpjax solver
(`nj.SemismoothNewton`, `nj.FixedPointVI`, jit-compiled) against the reference's
`solve_nivp.ImplicitEquationSolver` ('semismooth_newton' and 'VI'):

- nivpjax compile time (first call of a fresh `jax.jit`, tracing + XLA compilation) and the
  median run time after compilation (`jax.block_until_ready`, median of repeats of batches
  of back-to-back calls, so Python dispatch of the jitted call is included);
- the reference's median time per solve (a fresh solver object per solve, built outside the
  timed region: its VI rho and Newton lambda persist across solves);
- iterations, final residual (each package's own measure, see the notes printed below the
  table), max error against the exact solution, and the ratio reference / nivpjax time.

Problems (formulations of tests/test_nonlinear.py; the reference gets the same residual
through its own projections):

(a) relay, backward Euler step of x' = -w + d, w in Sign(x), sliding case
    (x_n = 0.05, d = 0.3, h = 0.1; exact x = 0, w = 0.8). nivpjax: Box(-1, 1) on the
    multiplier w with algebraic row -x. Reference: SignProjection (w-row of R is 0).
(b) unilateral contact impact, backward Euler step of a ball (q, v) with restitution 0.5
    (q_n = 1e-3, v_n = -1, h = 0.01; exact v = 0.5, q = q_n + 0.005). nivpjax:
    UnilateralContact. Reference: GeneralMoreauVIProjection, once with the literal gap
    g(y) = q (its ball example) and once with the gap predicted from the step start,
    g = q_n + h v_n / 2 (Moreau's rule, written into the gap callback).
(c) second-order-cone (De Saxce) friction impact, y = (v, lam) in R^3 x R^3, h = 1,
    mu = 0.3, v_n = (-1, 2, 0); exact (0, 1.7, 0, 1, -0.3, 0). nivpjax: SecondOrderCone on
    lam. Reference: no usable SOC projection in 0.1.2 (MuScaledSOCProjection is hard-wired to
    one notebook, prints on every call, and its tangent is broken), so a minimal
    `Projection` subclass applies its static kernel `_proj_mu_scaled_soc` to lam (tangent for
    semismooth Newton: central differences of that kernel).

Plus one batched line: `jax.vmap` over 1000 relay steps with different d, time per step.

Run from the repository root (about 30 s):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_step_solve
"""

import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
from solve_nivp.nonlinear_solvers import ImplicitEquationSolver
from solve_nivp.projections import (
    GeneralMoreauVIProjection,
    MuScaledSOCProjection,
    Projection,
    SignProjection,
)

import nivpjax as nj

from ._common import (
    G,
    auto_number,
    fmt_num,
    fmt_time,
    markdown_table,
    median_time,
    time_once,
)


TOL = 1e-10
NJ_SOLVERS = {
    "SemismoothNewton": nj.SemismoothNewton(rtol=TOL, atol=TOL, max_steps=100),
    "FixedPointVI": nj.FixedPointVI(rtol=TOL, atol=TOL, max_steps=500),
}
REF_METHOD = {"SemismoothNewton": "semismooth_newton", "FixedPointVI": "VI"}
REF_MAX_ITER = {"semismooth_newton": 100, "VI": 500}
WRONG = 1e-6  # a "converged" solve further than this from the exact solution is flagged


def _projector(projector, y_prev, h):
    def project(z, y, rho):
        ctx = nj.ProjectionContext(
            t=jnp.asarray(h), h=jnp.asarray(h), y_prev=y_prev, y_iter=y, rho=rho, args=None
        )
        return projector(z, ctx)

    return project


# --- (a) relay ---------------------------------------------------------------------------------
RELAY = dict(xn=0.05, d=0.3, h=0.1, w_prev=1.0)
RELAY_BOX = nj.BlockProjector([([1], nj.Box(-1.0, 1.0))])


def relay_exact(xn, d, h):
    w = d + xn / h
    if abs(w) <= 1:
        return np.array([0.0, w])
    w = np.sign(w)
    return np.array([xn + h * (d - w), w])


def nj_relay(solver, xn, d, h, w_prev):
    def residual(y):
        x, w = y
        return jnp.stack([(x - xn) / h - (-w + d), -x])

    y0 = jnp.stack([xn, w_prev])
    rho = jnp.stack([h, 1.0 / h])
    return solver.solve(residual, _projector(RELAY_BOX, y0, h), rho, y0)


class SignProjectionWBlock(SignProjection):
    """SignProjection with the solver's per-index rho restricted to the w entries (the
    reference's own class raises a shape error under its VI solver)."""

    def project(self, current_state, candidate, rhok=None, t=None, Fk_val=None):
        if rhok is not None and np.ndim(rhok) > 0:
            rhok = np.asarray(rhok)[np.atleast_1d(self.w_indices)]
        return super().project(current_state, candidate, rhok=rhok, t=t, Fk_val=Fk_val)


def ref_relay(proj_cls):
    p = RELAY
    yn = np.array([p["xn"], p["w_prev"]])

    def residual(y):
        # A = diag(1, 0), f = (-w + d, 0): the w-row is algebraic and identically zero.
        return np.array([(y[0] - p["xn"]) / p["h"] + y[1] - p["d"], 0.0])

    def make(method):
        return _ref_solver(
            method, proj_cls([0], [1]), [slice(0, 1), slice(1, 2)], yn, p["h"], p["h"]
        )

    return make, residual, yn


# --- (b) contact -------------------------------------------------------------------------------
CONTACT = dict(q0=1e-3, v0=-1.0, e=0.5, h=0.01)


def contact_exact(q0, v0, e, h):
    return np.array([q0 + h * (-e * v0), -e * v0])


def nj_contact(solver, q0, v0, e, h):
    proj = nj.UnilateralContact(
        gap=lambda t, y, a: y[:1],
        velocity_map=lambda t, y, a: jnp.array([[0.0, 1.0]], y.dtype),
        restitution=e,
    )
    y0 = jnp.stack([q0, v0])

    def residual(y):
        q, v = y
        return jnp.stack([(q - q0) / h - v, (v - v0) / h + G])

    return solver.solve(residual, _projector(proj, y0, h), jnp.full(2, h), y0)


def ref_contact(gap_kind):
    p = CONTACT
    q0, v0, e, h = p["q0"], p["v0"], p["e"], p["h"]
    yn = np.array([q0, v0])
    if gap_kind == "literal":
        gap = lambda t, y: np.array([y[0]])
    else:
        gap = lambda t, y: np.array([q0 + 0.5 * h * v0])

    def residual(y):
        return np.array([(y[0] - q0) / h - y[1], (y[1] - v0) / h + G])

    def make(method):
        proj = GeneralMoreauVIProjection(
            gap=gap,
            u_map=lambda t, y: np.array([y[1]]),
            J_u=lambda t, y: np.array([[0.0, 1.0]]),
            G_apply=lambda t, y, lam: np.array([0.0, lam[0]]),
            e=e,
            gap_tol=0.0,
            lcp_maxit=200,
            lcp_tol=1e-12,
        )
        return _ref_solver(method, proj, [slice(0, 1), slice(1, 2)], yn, h, h)

    return make, residual, yn


# --- (c) SOC friction --------------------------------------------------------------------------
SOC = dict(v0=(-1.0, 2.0, 0.0), mu=0.3, h=1.0)
SOC_EXACT = np.array([0.0, 1.7, 0.0, 1.0, -0.3, 0.0])


def _safe_norm(x):
    sq = jnp.sum(x**2)
    return jnp.where(sq > 0, jnp.sqrt(jnp.where(sq > 0, sq, 1.0)), 0.0)


def nj_soc(solver, v0, mu, h):
    proj = nj.BlockProjector([([3, 4, 5], nj.SecondOrderCone(mu))])

    def residual(y):
        v, lam = y[:3], y[3:]
        u_hat = jnp.concatenate([v[:1] + mu * _safe_norm(v[1:]), v[1:]])
        return jnp.concatenate([(v - v0) / h - lam, u_hat])

    y0 = jnp.concatenate([v0, jnp.zeros(3, v0.dtype)])
    rho = jnp.concatenate([jnp.full(3, h), jnp.full(3, 1.0 / h)])
    return solver.solve(residual, _projector(proj, y0, h), rho, y0)


class SOCKernelProjection(Projection):
    """The reference's static mu-scaled SOC kernel applied to one block of the state."""

    def __init__(self, mu, idx):
        super().__init__()
        self.mu = float(mu)
        self.idx = np.asarray(idx)

    def project(self, current_state, candidate, rhok=None, t=None, Fk_val=None):
        out = np.array(candidate, dtype=float, copy=True)
        out[self.idx] = MuScaledSOCProjection._proj_mu_scaled_soc(out[self.idx], self.mu)
        return out

    def tangent_cone(self, candidate, current_state, rhok=None, t=None, Fk_val=None):
        P = MuScaledSOCProjection._proj_mu_scaled_soc
        D = np.eye(candidate.shape[0])
        z = np.asarray(candidate, dtype=float)[self.idx]
        eps = 1e-7
        for j, k in enumerate(self.idx):
            dz = np.zeros_like(z)
            dz[j] = eps
            D[self.idx, k] = (P(z + dz, self.mu) - P(z - dz, self.mu)) / (2 * eps)
        return D


def ref_soc():
    v0, mu, h = np.array(SOC["v0"]), SOC["mu"], SOC["h"]
    yn = np.concatenate([v0, np.zeros(3)])

    def residual(y):
        v, lam = y[:3], y[3:]
        u_hat = np.concatenate([v[:1] + mu * np.linalg.norm(v[1:]), v[1:]])
        return np.concatenate([(v - v0) / h - lam, u_hat])

    def make(method):
        proj = SOCKernelProjection(mu, [3, 4, 5])
        return _ref_solver(method, proj, [slice(0, 3), slice(3, 6)], yn, h, h)

    return make, residual, yn


# --- the reference solver ----------------------------------------------------------------------
def _ref_solver(method, proj, slices, y_prev, h, t_end):
    s = ImplicitEquationSolver(
        method=method,
        proj=proj,
        component_slices=slices,
        tol=TOL,
        max_iter=REF_MAX_ITER[method],
    )
    # The context the reference's integrators set before each stage solve.
    s.current_time = t_end
    s.prev_state = y_prev
    s.prev_time = t_end - h
    s.prev_step = h
    return s


def run_reference(make, residual, yn, method, exact):
    """Median time per solve, iterations, residual (the reference's own measure), max error;
    or the exception it raises."""
    solve = lambda solver: solver.solve(residual, yn.copy())
    try:
        number = auto_number(solve, setup=lambda: make(method), target=0.02)
        t, out = median_time(solve, repeats=5, number=number, setup=lambda: make(method))
    except Exception as err:  # the reference's failure is a result here
        return dict(time=None, iters="-", res=f"{type(err).__name__}", err=None, ok=False)
    y, _, res, ok, iters = out
    return dict(time=t, iters=int(iters), res=float(res), err=_maxerr(y, exact), ok=bool(ok))


def _status(r):
    if not r["ok"]:
        return " (FAILED)"
    if r["err"] is not None and r["err"] > WRONG:
        return " (converged, WRONG)"
    return ""


def ref_relay_loop(method, ds, exact):
    """The reference on the same batch of relay steps, one solve after another (a fresh
    solver per step). Returns (time per step, #converged, max error) or (None, None, name of
    the exception)."""
    p = RELAY
    yn = np.array([p["xn"], p["w_prev"]])
    solvers = [
        _ref_solver(
            method, SignProjection([0], [1]), [slice(0, 1), slice(1, 2)], yn, p["h"], p["h"]
        )
        for _ in ds
    ]
    out = []
    t0 = time.perf_counter()
    try:
        for solver, d in zip(solvers, ds):
            residual = lambda y, d=d: np.array([(y[0] - p["xn"]) / p["h"] + y[1] - d, 0.0])
            out.append(solver.solve(residual, yn.copy()))
    except Exception as err:
        return None, None, type(err).__name__
    per_step = (time.perf_counter() - t0) / len(ds)
    ok = sum(bool(o[3]) for o in out)
    err = max(_maxerr(o[0], e) for o, e in zip(out, exact))
    return per_step, ok, err


def _maxerr(y, exact):
    y = np.asarray(y, float)
    if not np.all(np.isfinite(y)):
        return float("inf")
    return float(np.max(np.abs(y - exact)))


def run_nivpjax(fn, solver, args, exact):
    jitted = jax.jit(functools.partial(fn, solver))
    compile_s, sol = time_once(jitted, *args)
    number = auto_number(jitted, *args, target=0.05)
    t, sol = median_time(jitted, *args, repeats=7, number=number)
    # What a time stepper consumes: the value only (XLA drops the unused diagnostics).
    value_only = jax.jit(lambda *a: fn(solver, *a).value)
    time_once(value_only, *args)
    t_value, _ = median_time(value_only, *args, repeats=7, number=number)
    return dict(
        compile=compile_s,
        time=t,
        time_value=t_value,
        iters=int(sol.iterations),
        res=float(sol.residual_norm),
        err=_maxerr(sol.value, exact),
        ok=bool(sol.result == nj.RESULTS.successful),
    )


def main():
    f64 = lambda x: jnp.asarray(x, jnp.float64)
    problems = [
        (
            "(a) relay, sliding",
            nj_relay,
            tuple(f64(RELAY[k]) for k in ("xn", "d", "h", "w_prev")),
            relay_exact(RELAY["xn"], RELAY["d"], RELAY["h"]),
            [
                ("SignProjection", ref_relay(SignProjection)),
                # Only VI passes a per-index rho; for SSN the adapter would change nothing.
                ("SignProjection, rho[w] adapter", ref_relay(SignProjectionWBlock), ("VI",)),
            ],
        ),
        (
            "(b) contact impact, e=0.5",
            nj_contact,
            tuple(f64(CONTACT[k]) for k in ("q0", "v0", "e", "h")),
            contact_exact(**CONTACT),
            [
                ("GeneralMoreau, gap g(y)=q", ref_contact("literal")),
                ("GeneralMoreau, gap from step start", ref_contact("moreau")),
            ],
        ),
        (
            "(c) SOC friction impact",
            nj_soc,
            (f64(SOC["v0"]), f64(SOC["mu"]), f64(SOC["h"])),
            SOC_EXACT,
            [("static SOC kernel (adapter)", ref_soc())],
        ),
    ]
    headers = [
        "problem",
        "nivpjax solver",
        "compile",
        "run",
        "run (value only)",
        "iters",
        "residual",
        "max err",
        "reference (method, projection)",
        "ref run",
        "ref iters",
        "ref residual",
        "ref max err",
        "ref/nj",
    ]
    trivial = jax.jit(lambda x: x + 1.0)
    x6 = jnp.zeros(6)
    time_once(trivial, x6)
    floor, _ = median_time(trivial, x6, repeats=7, number=2000)
    rows = []
    nj_results = {}
    ref_timings = {}
    for name, fn, args, exact, refs in problems:
        for sname, solver in NJ_SOLVERS.items():
            r = run_nivpjax(fn, solver, args, exact)
            nj_results[(name, sname)] = r
            method = REF_METHOD[sname]
            for rname, (make, residual, yn), *only in refs:
                if only and method not in only[0]:
                    continue
                rr = run_reference(make, residual, yn, method, exact)
                ref_timings[(name, method, rname)] = rr
                # A time ratio against a failed or wrong reference solve is meaningless.
                valid = rr["time"] and _status(rr) == ""
                ratio = rr["time"] / r["time"] if valid else None
                rows.append(
                    [
                        name,
                        sname + _status(r),
                        fmt_time(r["compile"]),
                        fmt_time(r["time"]),
                        fmt_time(r["time_value"]),
                        r["iters"],
                        fmt_num(r["res"]),
                        fmt_num(r["err"]),
                        f"{method}, {rname}" + _status(rr),
                        fmt_time(rr["time"]),
                        rr["iters"],
                        fmt_num(rr["res"]),
                        fmt_num(rr["err"]),
                        "n/a (ref failed)" if ratio is None else f"{ratio:.0f}x",
                    ]
                )
    print("## One implicit step solve: nivpjax vs solve_nivp 0.1.2 (tol 1e-10)\n")
    print(markdown_table(headers, rows))
    print(
        "\nresidual: nivpjax = max|G(y)| with G(y) = y - P(y - rho R(y)) at the problem's rho; "
        "reference SSN = ||y - P(y - lam R(y))||_2 (lam-scaled), reference VI = blockwise "
        "relative RMS natural residual. max err = max-norm error of the returned state vs "
        "the exact solution. (FAILED) = the solver reported non-convergence or raised; "
        f"(converged, WRONG) = reported success but max err > {WRONG:g}. run = jitted call "
        "returning the whole NonlinearSolution (incl. the residual history buffer); run "
        "(value only) = jitted call returning only the solution value, as inside a time step. "
        "ref/nj uses the whole-solution run time. A trivial jitted call costs "
        f"{fmt_time(floor)} here (dispatch floor)."
    )

    # --- batched relay ---------------------------------------------------------------------
    n = 1000
    ds = jnp.linspace(-1.5, 1.5, n)
    xn, h, w_prev = (f64(RELAY[k]) for k in ("xn", "h", "w_prev"))
    exact = np.stack([relay_exact(float(xn), float(d), float(h)) for d in ds])
    print(f"\n## Batched: jax.vmap over {n} relay steps (x_n = 0.05, h = 0.1, d in [-1.5, 1.5])\n")
    brows = []
    for sname, solver in NJ_SOLVERS.items():
        batched = jax.jit(jax.vmap(lambda d, s=solver: nj_relay(s, xn, d, h, w_prev), in_axes=0))
        compile_s, sol = time_once(batched, ds)
        t, sol = median_time(batched, ds, repeats=7, number=3)
        ok = int(np.sum(np.asarray(sol.result._value) == nj.RESULTS.successful._value))
        err = float(np.max(np.abs(np.asarray(sol.value) - exact)))
        per_step = t / n
        ref_t, ref_ok, ref_err = ref_relay_loop(REF_METHOD[sname], np.asarray(ds), exact)
        ratio = f"{ref_t / per_step:.0f}x" if ref_t is not None and ref_ok == n else "n/a"
        brows.append(
            [
                sname,
                fmt_time(compile_s),
                fmt_time(t),
                fmt_time(per_step),
                f"{ok}/{n}",
                int(np.max(np.asarray(sol.iterations))),
                fmt_num(err),
                fmt_time(ref_t) if ref_t is not None else ref_err,
                "n/a" if ref_t is None else f"{ref_ok}/{n}",
                "n/a" if ref_t is None else fmt_num(ref_err),
                ratio,
            ]
        )
    print(
        markdown_table(
            [
                "nivpjax solver",
                "compile",
                "batch run",
                "per step",
                "converged",
                "max iters",
                "max err",
                "ref per step (Python loop)",
                "ref converged",
                "ref max err",
                "ref/nj per step",
            ],
            brows,
        )
    )


if __name__ == "__main__":
    main()
