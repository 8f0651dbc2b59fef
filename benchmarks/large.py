"""Large systems (issue 25): the strike-slip fault of `nivpjax.scenes.fault` against its size.

Four tables, each size in its own subprocess (so that its peak resident memory,
`resource.getrusage(...).ru_maxrss`, is its own):

1. **Cost per step** against the number of cells N, dense kernel (the study's files at
   10x10 and 20x20 cells, beyond them the dense matrix of the periodic spectral kernel) and
   spectral kernel: a solve capped at `--steps` attempted steps (the study's model and
   settings otherwise, `throw=False`), compile excluded (the fastest of up to three calls
   after the first): seconds per attempted step, Newton iterations per attempt, peak
   memory. A size is skipped when the
   previous one's time per step, scaled by (N'/N)^3, predicts more than `--budget` seconds.
2. **Where the time goes** in one Newton iteration: one residual (two kernel products),
   the dense Jacobian by `jax.jacfwd` (3N products), and its LU solve (lineax), timed apart.
3. **Whole trajectories** at the study's settings (t in [0, 34.641], rtol 1e-3,
   atol 1e-6) for the sizes whose projected time fits `--budget`: compile, run, steps,
   mean final slip.
4. **Against the reference** `solve_nivp.solve_ivp_ns` (the study's baseline: composite
   scheme, Coulomb projection, VI solver tol 1e-6, h0 5e-3, h in [1e-7, 1e3], factors in
   [0.6, 1.8], method_order 1) at 10x10 (3 km patch) and 20x20 (5 km x 4 km), side by
   side: time and the error of the mean final slip against nivpjax at a tight tolerance
   (`--tight`), with nivpjax at several tolerances; the ratio at equal accuracy compares
   the reference with the cheapest nivpjax run at least as accurate.

The nonlinear solver is a command-line option (`--solver`, a Python expression with `nj`
in scope, default `nj.SemismoothNewton()`), so the runs can be repeated with another one
(e.g. a matrix-free Newton once it exists). Every run is float64, OPENBLAS_NUM_THREADS=1.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.large            # full (tens of minutes)
    OPENBLAS_NUM_THREADS=1 python -m benchmarks.large --quick    # small sizes, ~3 minutes

Writes benchmarks/results/large.md, large.json and large.png (log-log cost per step and
memory against N).
"""

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
KERNELS = Path(os.environ.get("NIVPJAX_FAULT_KERNELS", "/work/shared/fault"))
STUDY_FILES = {
    (10, 10): ("kijs_10x10elem-3x3length.npy", 3.0, 3.0),
    (20, 20): ("kijs_20x20elem-5x4length.npy", 5.0, 4.0),
}
SECOND = 1000.0  # ms


# --- one size, in a subprocess -----------------------------------------------------------------
def _setup_jax():
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    import jax

    jax.config.update("jax_enable_x64", True)
    return jax


def build(kernel, nx):
    """The study's fault at nx x nx cells: `kernel` "dense" (the study's file where there is
    one, else the dense matrix of the periodic kernel) or "spectral"."""
    from nivpjax import scenes

    file = STUDY_FILES.get((nx, nx))
    if kernel == "spectral":
        length, depth = 3.0, 3.0
        scene, x0, args = scenes.fault("spectral", nx, nx, length=length, depth=depth)
    elif file is not None and (KERNELS / file[0]).exists():
        name, length, depth = file
        K = scenes.load_fault_kernel(KERNELS / name)
        scene, x0, args = scenes.fault(K, nx, nx, length=length, depth=depth)
    else:
        length, depth = 3.0, 3.0
        K = periodic_dense(nx, nx, 1.0, depth / length)
        scene, x0, args = scenes.fault(K, nx, nx, length=length, depth=depth)
    t1 = 30 * SECOND / scenes.fault_units(length)["time_ms"]
    return scene, x0, args, t1


def periodic_dense(nx, nz, lx, lz):
    """The dense matrix of the periodic spectral kernel (its columns by FFT)."""
    from nivpjax._elastic import spectral_apply_np, spectral_symbol

    sym = spectral_symbol(nx, nz, lx, lz)
    n = nx * nz
    K = np.stack([spectral_apply_np(sym, e, nx, nz) for e in np.eye(n)], axis=1)
    return 0.5 * (K + K.T)


def make_solve(scene, solver_expr, max_steps, save_final=True):
    import equinox as eqx

    import nivpjax as nj

    solver = eval(solver_expr, {"nj": nj})

    @eqx.filter_jit
    def solve(x0, args, t1, rtol, atol):
        return scene.solve(
            0.0,
            t1,
            x0,
            args,
            stepper=nj.Bathe(solver=solver),
            controller=nj.PIDController(rtol=rtol, atol=atol),
            max_steps=max_steps,
            saveat=nj.SaveAt(),
            throw=False,
        )

    return solve


def run_one(spec):
    """Measure one configuration (a dict); returns a dict of numbers."""
    jax = _setup_jax()
    import jax.numpy as jnp

    t_setup = time.perf_counter()
    scene, x0, args, t1 = build(spec["kernel"], spec["nx"])
    n = x0.shape[0] // 3
    out = dict(spec, N=n, setup_s=time.perf_counter() - t_setup)
    if spec["mode"] == "parts":
        out.update(time_parts(jax, scene, x0, args))
    elif spec["mode"] == "vmap":
        out.update(time_vmap(jax, scene, x0, args, t1, spec))
    elif spec["mode"] == "grad":
        out.update(gradient_check(jax, scene, x0, args, t1, spec))
    else:
        max_steps = spec["steps"] if spec["mode"] == "step" else spec.get("max_steps", 100_000)
        solve = make_solve(scene, spec["solver"], max_steps)
        call = (x0, args, jnp.asarray(t1), jnp.asarray(spec["rtol"]), jnp.asarray(spec["atol"]))
        t0 = time.perf_counter()
        sol = jax.block_until_ready(solve(*call))
        first = time.perf_counter() - t0
        # The fastest of up to 3 further calls (those under 3 s each): one sample of a
        # sub-second run on a 2-core machine varied by 20-40% between runs.
        run, cpu = float("inf"), float("inf")
        for _ in range(3):
            t0, c0 = time.perf_counter(), time.process_time()
            sol = jax.block_until_ready(solve(*call))
            wall = time.perf_counter() - t0
            if wall < run:
                run, cpu = wall, time.process_time() - c0
            if wall > 3.0:
                break
        attempts = int(sol.n_accepted) + int(sol.n_rejected)
        out.update(
            compile_s=first - run,
            run_s=run,
            cpu_s=cpu,
            accepted=int(sol.n_accepted),
            rejected=int(sol.n_rejected),
            newton=int(sol.n_iterations),
            per_step_s=run / max(attempts, 1),
            per_step_cpu_s=cpu / max(attempts, 1),
            newton_per_step=int(sol.n_iterations) / max(attempts, 1),
            t_final=float(sol.t_final) if hasattr(sol, "t_final") else float("nan"),
            mean_slip=float(jnp.mean(sol.y_final[2 * n : 3 * n])),
            result=str(sol.result),
        )
    out["maxrss_MB"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def time_parts(jax, scene, x0, args):
    """Seconds for one residual, one dense Jacobian (`jacfwd`) and one dense LU solve."""
    import jax.numpy as jnp
    import lineax as lx

    x = jnp.asarray(x0)

    def f(y):
        return scene.dynamics(0.0, y, args, {})

    res = jax.jit(f)
    jac = jax.jit(jax.jacfwd(f))

    lu_solve = jax.jit(lambda A, b: lx.linear_solve(lx.MatrixLinearOperator(A), b, lx.LU()).value)
    A = jnp.eye(x.shape[0]) - 0.01 * jac(x)

    def timed(fn, *a):
        jax.block_until_ready(fn(*a))
        reps, t0 = 0, time.perf_counter()
        while reps < 3 or time.perf_counter() - t0 < 0.5:
            jax.block_until_ready(fn(*a))
            reps += 1
        return (time.perf_counter() - t0) / reps

    return dict(residual_s=timed(res, x), jacobian_s=timed(jac, x), lu_s=timed(lu_solve, A, x))


def _mean_slip_fn(scene, x0, t1, spec, **kw):
    import jax.numpy as jnp

    import nivpjax as nj

    solver = eval(spec["solver"], {"nj": nj})
    n = x0.shape[0] // 3

    def mean_slip(args):
        sol = scene.solve(
            0.0,
            t1,
            x0,
            args,
            stepper=nj.Bathe(solver=solver),
            controller=nj.PIDController(rtol=spec["rtol"], atol=spec["atol"]),
            max_steps=spec.get("max_steps", 20_000),
            saveat=nj.SaveAt(),
            throw=False,
            **kw,
        )
        return jnp.mean(sol.y_final[2 * n :]), sol.result

    return mean_slip


def time_vmap(jax, scene, x0, args, t1, spec):
    """`jax.vmap` of whole trajectories over `draws` parameter draws (zeta and Dc, +-20 %),
    against one trajectory: seconds per trajectory, compile apart."""
    import jax.numpy as jnp

    mean_slip = _mean_slip_fn(scene, x0, t1, spec)
    rng = np.random.default_rng(0)
    draws = spec["draws"]
    zeta = jnp.asarray(args["zeta"] * rng.uniform(0.8, 1.2, draws))
    dc = jnp.asarray(args["Dc"] * rng.uniform(0.8, 1.2, draws))

    def one(z, d):
        return mean_slip(dict(args, zeta=z, Dc=d))

    batched = jax.jit(jax.vmap(one))
    single = jax.jit(one)
    out = {}
    for name, fn, call in (("single", single, (zeta[0], dc[0])), ("vmap", batched, (zeta, dc))):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*call))
        first = time.perf_counter() - t0
        t0, c0 = time.perf_counter(), time.process_time()
        slips, results = jax.block_until_ready(fn(*call))
        run, cpu = time.perf_counter() - t0, time.process_time() - c0
        k = draws if name == "vmap" else 1
        out[name] = dict(compile_s=first - run, run_s=run, cpu_s=cpu, per_traj_s=run / k)
    import nivpjax as nj

    out["failed"] = int(jnp.sum(~(results == nj.RESULTS.successful)))
    out["spread"] = [float(np.min(slips)), float(np.max(slips))]
    return out


def gradient_check(jax, scene, x0, args, t1, spec):
    """d(mean final slip)/dDc by reverse mode against central differences (+-1 %)."""
    import jax.numpy as jnp

    mean_slip = _mean_slip_fn(scene, x0, t1, spec)

    def f(dc):
        return mean_slip(dict(args, Dc=dc))[0]

    dc = jnp.asarray(args["Dc"])
    t0 = time.perf_counter()
    value, grad = jax.block_until_ready(jax.jit(jax.value_and_grad(f))(dc))
    t_grad = time.perf_counter() - t0
    eps = 1e-2 * float(dc)
    fj = jax.jit(f)
    fd = (float(fj(dc + eps)) - float(fj(dc - eps))) / (2 * eps)
    return dict(
        value=float(value),
        grad=float(grad),
        fd=fd,
        rel_diff=abs(float(grad) - fd) / abs(fd),
        grad_s_with_compile=t_grad,
    )


def spawn(spec, timeout):
    cmd = [sys.executable, "-m", "benchmarks.large", "--one", json.dumps(spec)]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    try:
        p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return dict(spec, error=f"timed out after {timeout} s")
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode != 0 or not lines:
        return dict(spec, error=(p.stderr or p.stdout)[-400:])
    return json.loads(lines[-1])


# --- the reference ----------------------------------------------------------------------------
def run_reference(nx):
    """The study's baseline run of `solve_nivp` on the same model (same K, E, sigma, y0)."""
    import scipy.sparse as sp
    import solve_nivp

    _setup_jax()
    scene, x0, args, t1 = build("dense", nx)
    a = {k: np.asarray(v) for k, v in args.items()}
    n = a["K"].shape[0]
    K, E, sigma = a["K"], 2 * a["zeta"] * a["R"], a["sigma"]
    slices = [slice(0, n), slice(n, 2 * n), slice(2 * n, 3 * n)]

    def rhs(t, y):
        v, u = y[:n], y[n : 2 * n]
        return np.concatenate([-(K @ u) - E @ v, v, np.abs(v)])

    def friction(y, t=None, Fk_val=None):
        out = np.zeros_like(y)
        out[:n] = (0.5 + 0.1 * np.exp(-y[2 * n :] / 1000.0)) * sigma
        return out

    kwargs = dict(
        fun=rhs,
        t_span=(0.0, t1),
        y0=np.asarray(x0),
        method="composite",
        projection="coulomb",
        solver="VI",
        projection_opts=dict(
            con_force_func=friction,
            rhok=np.ones(n),
            component_slices=slices,
            constraint_indices=list(range(n)),
            use_numba=True,
        ),
        # The study's SOLVER_OPTS_SSN (with tol and max_iter alone its VI stalls at 20x20
        # and returns no slip).
        solver_opts=dict(
            tol=1e-6,
            max_iter=100,
            vi_strict_block_lipschitz=False,
            vi_max_block_adjust_iters=10,
            globalization="line_search",
        ),
        adaptive=True,
        adaptive_opts=dict(
            h0=5e-3,
            h_min=1e-7,
            h_down=0.6,
            h_up=1.8,
            method_order=1,
            controller="H211b",
            b_param=4.0,
            skip_error_indices=[],
        ),
        h0=5e-3,
        component_slices=slices,
        A=sp.identity(3 * n, format="csr"),
    )
    t0, c0 = time.perf_counter(), time.process_time()
    ts, ys, *_ = solve_nivp.solve_ivp_ns(**kwargs)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return dict(
        nx=nx,
        N=n,
        run_s=wall,
        cpu_s=cpu,
        steps=len(ts) - 1,
        t_final=float(ts[-1]),
        mean_slip=float(np.mean(ys[-1, 2 * n :])),
        maxrss_MB=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    )


# --- driver -----------------------------------------------------------------------------------
def _projected(prev, n, steps):
    """Seconds for `steps` attempts at N = n from the measured rows `prev` (the slope of
    the last two in log-log, else cubic)."""
    a = prev[-1]
    slope = 3.0
    if len(prev) >= 2:
        b = prev[-2]
        slope = max(1.0, np.log(a["per_step_s"] / b["per_step_s"]) / np.log(a["N"] / b["N"]))
    return a["per_step_s"] * steps * (n / a["N"]) ** slope


def step_sweep(kernel, sizes, solver, opts, log):
    rows, done = [], []
    for nx in sizes:
        n = nx * nx
        if done:
            projected = _projected(done, n, opts.steps)
            if projected > opts.budget:
                log(f"  {solver} {kernel} {nx}x{nx}: skipped (projected {projected:.0f} s)")
                rows.append(
                    dict(kernel=kernel, solver=solver, nx=nx, N=n, skipped=f"{projected:.0f} s")
                )
                break
        spec = dict(mode="step", kernel=kernel, nx=nx, steps=opts.steps, rtol=1e-3, atol=1e-6)
        row = spawn(dict(spec, solver=solver), timeout=opts.budget * 3 + 180)
        log(f"  {solver} {kernel} {nx}x{nx}: {_brief(row)}")
        rows.append(row)
        if "error" in row:
            break
        done.append(row)
    return rows


def _brief(row):
    if row is None:
        return "not run"
    if "error" in row:
        return "error: " + row["error"].strip().splitlines()[-1][:200]
    if "skipped" in row:
        return "skipped: projected " + row["skipped"]
    keys = ("per_step_s", "per_step_cpu_s", "newton_per_step", "run_s", "cpu_s", "accepted")
    keys += ("rejected", "mean_slip")
    text = ", ".join(f"{k}={row[k]:.4g}" for k in keys if k in row)
    return text + f", {row['maxrss_MB']:.0f} MB"


def trajectory(kernel, nx, solver, rtol, steps_rows, opts, log, expected_attempts=400):
    """One whole trajectory, unless the cost per step measured at that size projects it
    past the budget."""
    n = nx * nx
    measured = [
        r
        for r in steps_rows
        if r.get("solver") == solver and r.get("kernel") == kernel and "per_step_s" in r
    ]
    if measured:
        near = min(measured, key=lambda r: abs(np.log(r["N"] / n)))
        projected = near["per_step_s"] * expected_attempts * max(1.0, n / near["N"]) ** 1.5
        if projected > opts.budget * 2:
            row = dict(kernel=kernel, nx=nx, N=n, solver=solver, rtol=rtol)
            return dict(row, skipped=f"{projected:.0f} s")
    atol = 1e-6 if rtol >= 1e-3 else 1e-3 * rtol
    spec = dict(mode="trajectory", kernel=kernel, nx=nx, solver=solver, rtol=rtol, atol=atol)
    return spawn(spec, opts.budget * 3 + 180)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes only")
    parser.add_argument(
        "--solver",
        action="append",
        help="nonlinear solver (Python expression, `nj` in scope); repeat for several "
        "(default: nj.SemismoothNewton() and nj.FixedPointVI())",
    )
    parser.add_argument("--truth-solver", default="nj.FixedPointVI()")
    parser.add_argument("--batch-solver", default="nj.SemismoothNewton()", help="vmap, grad")
    parser.add_argument("--steps", type=int, default=30, help="attempts per cost-per-step run")
    parser.add_argument("--budget", type=float, default=300.0, help="seconds per run")
    parser.add_argument("--tight", type=float, default=1e-7, help="rtol of the truth run")
    parser.add_argument("--no-reference", action="store_true")
    parser.add_argument("--vmap-nx", type=int, default=None, help="spectral cells per side")
    parser.add_argument("--vmap-draws", type=int, default=None)
    parser.add_argument("--grad-nx", type=int, default=None, help="dense cells per side")
    parser.add_argument(
        "--trajectory-sizes",
        type=lambda text: [int(x) for x in text.split(",")],
        default=[16, 32, 100, 316],
        help="cells per side of the spectral trajectories, comma-separated",
    )
    parser.add_argument(
        "--dense-trajectory-sizes",
        type=lambda text: [int(x) for x in text.split(",") if x],
        default=[32, 50, 100],
        help="cells per side of the dense-kernel trajectories (first solver only)",
    )
    parser.add_argument(
        "--compare-only",
        action="store_true",
        help="only the comparison with the reference; writes large-compare.{md,json}",
    )
    parser.add_argument(
        "--compare-rtols",
        type=lambda text: [float(x) for x in text.split(",")],
        default=[1e-2, 3e-3, 2e-3, 1e-3, 1e-4],
        help="nivpjax's tolerances in the comparison, comma-separated",
    )
    parser.add_argument("--one", help=argparse.SUPPRESS)
    parser.add_argument("--reference-one", type=int, help=argparse.SUPPRESS)
    opts = parser.parse_args(argv)
    if opts.one:
        print(json.dumps(run_one(json.loads(opts.one))))
        return
    if opts.reference_one:
        print(json.dumps(run_reference(opts.reference_one)))
        return
    solvers = opts.solver or ["nj.SemismoothNewton()", "nj.FixedPointVI()"]
    t_start = time.perf_counter()
    # The issue's sizes: 64 draws at ~10^3 cells, the gradient at 400 cells.
    vmap_nx = opts.vmap_nx or (4 if opts.quick else 32)
    draws = opts.vmap_draws or (8 if opts.quick else 64)
    grad_nx = opts.grad_nx or (10 if opts.quick else 20)

    def log(msg):
        print(msg, flush=True)

    dense_sizes = [4, 10, 20] if opts.quick else [4, 10, 20, 32, 50, 100]
    spectral_sizes = [4, 8, 16, 32] if opts.quick else [8, 16, 32, 100, 316, 1000]
    log(f"solvers: {solvers}")
    if opts.compare_only:
        compare = compare_reference(solvers, [], opts, log)
        report = dict(
            solvers=solvers,
            truth_solver=opts.truth_solver,
            machine=f"{platform.machine()}, {os.cpu_count()} cores, float64",
            load=os.getloadavg(),
            date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            compare=compare,
        )
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / "large-compare.json").write_text(json.dumps(report, indent=1))
        head = [
            "# The fault against the reference",
            "",
            f"`python -m benchmarks.large --compare-only` on {report['date']}; "
            f"{report['machine']}, load average {report['load'][0]:.1f} (a shared machine: "
            "wall times are inflated; CPU time is the steadier measure).",
        ]
        (RESULTS / "large-compare.md").write_text("\n".join(head + compare_markdown(report)) + "\n")
        elapsed = time.perf_counter() - t_start
        log(f"written to benchmarks/results/large-compare.md ({elapsed:.0f} s)")
        return
    log("cost per step:")
    steps = []
    for solver in solvers:
        steps += step_sweep("dense", dense_sizes, solver, opts, log)
        steps += step_sweep("spectral", spectral_sizes, solver, opts, log)
    log("where the time goes (one Newton iteration):")
    parts = []
    for kernel, sizes in (("dense", [10, 20]), ("spectral", [10, 20])):
        for nx in sizes:
            row = spawn(dict(mode="parts", kernel=kernel, nx=nx), timeout=opts.budget + 120)
            parts.append(row)
            keys = ("residual_s", "jacobian_s", "lu_s")
            text = ", ".join(f"{k}={row[k]:.3g}" for k in keys if k in row)
            log(f"  {kernel} {nx}x{nx}: {text}{row.get('error', '')[-200:]}")
    log("whole trajectories against N (spectral kernel, rtol 1e-3):")
    scaling = []
    for solver in solvers:
        for nx in [8, 16, 32] if opts.quick else opts.trajectory_sizes:
            row = trajectory("spectral", nx, solver, 1e-3, steps, opts, log)
            log(f"  {solver} spectral {nx}x{nx}: {_brief(row)}")
            scaling.append(row)
    for nx in [] if opts.quick else opts.dense_trajectory_sizes:
        row = trajectory("dense", nx, solvers[0], 1e-3, steps, opts, log)
        log(f"  {solvers[0]} dense {nx}x{nx}: {_brief(row)}")
        scaling.append(row)
    log("vmap over parameter draws and the gradient with respect to Dc:")
    vm_spec = dict(mode="vmap", kernel="spectral", nx=vmap_nx, draws=draws)
    vm = spawn(dict(vm_spec, solver=opts.batch_solver, rtol=1e-3, atol=1e-6), opts.budget * 4)
    log(f"  vmap {vmap_nx}x{vmap_nx} x {draws}: {json.dumps(vm)[:400]}")
    gr_spec = dict(mode="grad", kernel="dense", nx=grad_nx, solver=opts.batch_solver)
    gr = spawn(dict(gr_spec, rtol=1e-6, atol=1e-6), opts.budget * 4)
    log(f"  grad {grad_nx}x{grad_nx}: {json.dumps(gr)[:400]}")
    compare = compare_reference(solvers, steps, opts, log)
    report = dict(
        solvers=solvers,
        truth_solver=opts.truth_solver,
        batch_solver=opts.batch_solver,
        machine=f"{platform.machine()}, {os.cpu_count()} cores, float64",
        load=os.getloadavg(),
        date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        steps=steps,
        parts=parts,
        scaling=scaling,
        vmap=vm,
        grad=gr,
        compare=compare,
        quick=opts.quick,
    )
    name = "large-quick" if opts.quick else "large"
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(report, indent=1))
    (RESULTS / f"{name}.md").write_text(markdown(report))
    plot(report, RESULTS / f"{name}.png")
    log(f"written to benchmarks/results/{name}.md ({time.perf_counter() - t_start:.0f} s)")


def compare_reference(solvers, steps, opts, log):
    """The reference against nivpjax at the study's dense kernels (10x10, and 20x20 unless
    `--quick`): a tight-tolerance truth, nivpjax at `--compare-rtols`, the reference."""
    log("against the reference (dense study kernels):")
    compare = []
    for nx in [10] if opts.quick else [10, 20]:
        truth = spawn(
            dict(
                mode="trajectory",
                kernel="dense",
                nx=nx,
                solver=opts.truth_solver,
                rtol=opts.tight,
                atol=1e-3 * opts.tight,
            ),
            opts.budget * 4,
        )
        log(f"  truth {nx}x{nx} ({opts.truth_solver}, rtol {opts.tight:g}): {_brief(truth)}")
        runs = []
        for solver in solvers:
            for rtol in opts.compare_rtols:
                row = trajectory("dense", nx, solver, rtol, steps, opts, log)
                log(f"  {solver} {nx}x{nx} rtol {rtol:g}: {_brief(row)}")
                runs.append(row)
        ref = None if opts.no_reference else _spawn_reference(nx, opts.budget * 4)
        log(f"  reference {nx}x{nx}: {_brief(ref)}")
        compare.append(dict(nx=nx, truth=truth, runs=runs, reference=ref))
    return compare


def _spawn_reference(nx, timeout):
    cmd = [sys.executable, "-m", "benchmarks.large", "--reference-one", str(nx)]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    try:
        p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return dict(nx=nx, error=f"timed out after {timeout} s")
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode != 0 or not lines:
        return dict(nx=nx, error=(p.stderr or p.stdout)[-400:])
    return json.loads(lines[-1])


# --- report -----------------------------------------------------------------------------------
def _fmt(x, spec=".3g"):
    return "–" if x is None else format(x, spec)


def _compile(row):
    # A run of minutes varies by more than its compile time: the difference is then noise.
    if row["compile_s"] < 1.0:
        return f"< 1 (first call {row['compile_s'] + row['run_s']:.3g} s)"
    return _fmt(row["compile_s"], ".1f")


def _row_or_note(row):
    if row is None:
        return "not run"
    if "skipped" in row:
        return f"skipped (projected {row['skipped']})"
    return row.get("error", "").strip().splitlines()[-1][:80] if row.get("error") else ""


def _slopes(steps, n_min=1000):
    """Least-squares exponents of the wall time per step in N, per solver and kernel, over
    the rows with at least `n_min` cells."""
    lines = []
    keys = sorted({(x.get("solver", ""), x["kernel"]) for x in steps})
    for solver, kernel in keys:
        rows = [
            x
            for x in steps
            if x.get("solver", "") == solver and x["kernel"] == kernel and "per_step_s" in x
        ]
        rows = [x for x in rows if x["N"] >= n_min]
        if len(rows) < 2:
            continue
        n = np.log([x["N"] for x in rows])
        t = np.log([x["per_step_s"] for x in rows])
        slope = np.polyfit(n, t, 1)[0]
        lines.append(
            f"- `{solver}`, {kernel} kernel: wall time per step grows like N^{slope:.2f} "
            f"from {rows[0]['N']} to {rows[-1]['N']} cells."
        )
    return lines


def markdown(r):
    out = [
        "# Large systems: the fault against its size",
        "",
        f"`python -m benchmarks.large{' --quick' if r['quick'] else ''}` on {r['date']}; "
        f"{r['machine']}, load average {r['load'][0]:.1f} (a shared machine: wall times "
        "are inflated; CPU time, all threads, is the steadier measure). Bathe's scheme, "
        "PID controller rtol 1e-3, atol 1e-6 unless stated. The study's model "
        "(`nivpjax.scenes.fault`); dense kernels: the study's files at 10x10 (3 km) and "
        "20x20 (5 km x 4 km), the dense matrix of the periodic kernel at other sizes.",
        "",
        "## Cost per step",
        "",
        f"A solve capped at {r['steps'][0].get('steps', '')} attempted steps from the "
        "study's initial state, compile excluded.",
        "",
        "| solver | kernel | cells N | unknowns | wall s / step | CPU s / step | "
        "iterations / step | attempts | compile s | peak memory MB |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in r["steps"]:
        head = f"| `{s.get('solver', '')}` | {s['kernel']} | {s.get('N', s['nx'] ** 2)} |"
        if "per_step_s" not in s:
            out.append(f"{head} | {_row_or_note(s)} | | | | | |")
            continue
        out.append(
            f"{head} {3 * s['N']} | {_fmt(s['per_step_s'])} | {_fmt(s['per_step_cpu_s'])} | "
            f"{_fmt(s['newton_per_step'], '.1f')} | {s['accepted'] + s['rejected']} | "
            f"{_fmt(s['compile_s'], '.1f')} | {_fmt(s['maxrss_MB'], '.0f')} |"
        )
    out += [""] + _slopes(r["steps"])
    out += [
        "",
        "## Where the time goes (the parts of one Newton iteration, seconds)",
        "",
        "A VI (projection) iteration costs about two residuals. A matrix-free Newton "
        "iteration (`Krylov`, the default above 128 unknowns) costs one residual for its "
        "line search and one product per GMRES iteration, each about a residual; the "
        "dense path (`DenseLU`, the default up to 128 unknowns) a residual, the Jacobian "
        "and its LU, timed here to show why it is not used beyond.",
        "",
        "| kernel | cells N | residual (2 kernel products) | dense Jacobian (jacfwd) | LU solve |",
        "|---|---|---|---|---|",
    ]
    for p in r["parts"]:
        out.append(
            f"| {p['kernel']} | {p.get('N', '')} | {_fmt(p.get('residual_s'))} | "
            f"{_fmt(p.get('jacobian_s'))} | {_fmt(p.get('lu_s'))} |"
        )
    out += [
        "",
        "## Whole trajectories against N (rtol 1e-3, t in [0, 34.641])",
        "",
        "Compile s: the first call's time beyond the fastest later one. Set-up s: building "
        "the scene (for a dense kernel its square root and the initial state by one "
        "`eigh`), once per kernel, outside the solve.",
        "",
        "| solver | kernel | cells N | wall s | CPU s | compile s | set-up s | "
        "steps (acc/rej) | iterations | mean final slip | peak MB |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for x in r["scaling"]:
        head = f"| `{x.get('solver', '')}` | {x.get('kernel', '')} | {x.get('N', '')} |"
        if "run_s" not in x:
            out.append(f"{head} {_row_or_note(x)} | | | | | | | | |")
            continue
        out.append(
            f"{head} {_fmt(x['run_s'])} | {_fmt(x['cpu_s'])} | {_compile(x)} | "
            f"{_fmt(x.get('setup_s'), '.1f')} | {x['accepted']}/{x['rejected']} | "
            f"{x['newton']} | {_fmt(x['mean_slip'], '.6g')} | "
            f"{_fmt(x['maxrss_MB'], '.0f')} |"
        )
    vm, gr = r.get("vmap") or {}, r.get("grad") or {}
    out += ["", "## vmap over parameter draws; the gradient with respect to Dc", ""]
    if "vmap" in vm:
        out.append(
            f"- `jax.vmap` of {vm['draws']} trajectories (zeta and Dc drawn +-20 %), "
            f"spectral kernel, {vm['N']} cells, `{vm['solver']}`: "
            f"{vm['vmap']['per_traj_s']:.3g} s per trajectory (one alone: "
            f"{vm['single']['run_s']:.3g} s; compile {vm['vmap']['compile_s']:.0f} s); "
            f"{vm['failed']} failed; mean final slip from {vm['spread'][0]:.5g} to "
            f"{vm['spread'][1]:.5g}."
        )
    else:
        out.append(f"- vmap: {(vm.get('error') or 'not run')[-300:]}")
    if "grad" in gr:
        out.append(
            f"- d(mean final slip)/dDc at {gr['N']} cells (dense kernel, rtol 1e-6, "
            f"`{gr['solver']}`): reverse mode {gr['grad']:.6g}, central differences "
            f"(+-1 %) {gr['fd']:.6g}, relative difference {gr['rel_diff']:.2e} "
            f"({gr['grad_s_with_compile']:.0f} s with compile)."
        )
    else:
        out.append(f"- gradient: {(gr.get('error') or 'not run')[-300:]}")
    small = r.get("grad_small")
    if small and "grad" in small:
        out.append(
            f"- The same at {small['N']} cells (`--one` run of the `grad` mode): reverse mode "
            f"{small['grad']:.6g}, central differences {small['fd']:.6g}, relative "
            f"difference {small['rel_diff']:.2e} ({small['grad_s_with_compile']:.0f} s "
            "with compile)."
        )
    return "\n".join(out + compare_markdown(r)) + "\n"


def compare_markdown(r):
    """The lines of the comparison with the reference (`r["compare"]`)."""
    out = [
        "",
        "## Against the reference (the study's settings; t in [0, 34.641] at 10x10, "
        "[0, 20.785] at 20x20: 30 s)",
        "",
        f"Error: |mean final slip - truth| / truth, truth = `{r['truth_solver']}` at rtol "
        "1e-7. Times: nivpjax's fastest of up to three calls after the first (compile "
        "apart), the reference's one run "
        "(`solve_nivp.solve_ivp_ns`, composite, Coulomb projection, VI tol 1e-6, h0 5e-3, "
        "factors [0.6, 1.8], method_order 1, rtol 1e-3, atol 1e-6).",
        "",
        "| cells | run | rtol | wall s | CPU s | compile s | steps (acc/rej) | "
        "mean final slip | error | peak MB |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in r["compare"]:
        truth = c["truth"].get("mean_slip")

        def err(row, truth=truth):
            if truth is None or row is None or "mean_slip" not in row:
                return None
            return abs(row["mean_slip"] - truth) / truth

        rows = [("truth", c["truth"])] + [(f"`{x['solver']}`", x) for x in c["runs"]]
        for label, row in rows + [("reference", c["reference"])]:
            head = f"| {c['nx']}x{c['nx']} | {label} | {_fmt((row or {}).get('rtol'), 'g')} |"
            if row is None or "run_s" not in row:
                out.append(f"{head} {_row_or_note(row)} | | | | | | |")
                continue
            steps = (
                f"{row['accepted']}/{row['rejected']}"
                if "accepted" in row
                else f"{row.get('steps')} acc."
            )
            out.append(
                f"{head} {_fmt(row['run_s'])} | {_fmt(row.get('cpu_s'))} | "
                f"{_fmt(row.get('compile_s'), '.1f')} | {steps} | "
                f"{_fmt(row.get('mean_slip'), '.6g')} | {_fmt(err(row), '.2e')} | "
                f"{_fmt(row.get('maxrss_MB'), '.0f')} |"
            )
        ref = c["reference"]
        if ref and "cpu_s" in ref and err(ref) is not None and err(ref) > 0.1:
            out += [
                "",
                f"- {c['nx']}x{c['nx']}: the reference's answer is wrong (error "
                f"{err(ref):.2g}): no ratio at equal accuracy.",
                "",
            ]
        elif ref and "cpu_s" in ref and err(ref) is not None:
            out.append("")
            for solver in r["solvers"]:
                good = [
                    x
                    for x in c["runs"]
                    if x.get("solver") == solver and err(x) is not None and err(x) <= err(ref)
                ]
                if good:
                    best = min(good, key=lambda x: x["cpu_s"])
                    out.append(
                        f"- {c['nx']}x{c['nx']}, `{solver}`: at equal or better accuracy "
                        f"(rtol {best['rtol']:g}) {best['cpu_s']:.3g} CPU s against the "
                        f"reference's {ref['cpu_s']:.3g}: "
                        f"**{ref['cpu_s'] / best['cpu_s']:.1f}x**."
                    )
            out.append("")
    return out


def plot(r, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    markers = {"dense": "o", "spectral": "s"}
    for solver in r["solvers"]:
        for kernel, marker in markers.items():
            rows = [
                s
                for s in r["steps"]
                if s["kernel"] == kernel and s.get("solver") == solver and "per_step_s" in s
            ]
            if not rows:
                continue
            n = np.array([s["N"] for s in rows])
            label = f"{kernel}, {solver}"
            axes[0].loglog(n, [s["per_step_cpu_s"] for s in rows], marker + "-", label=label)
            axes[1].loglog(n, [s["maxrss_MB"] for s in rows], marker + "-", label=label)
    n = np.logspace(1, 6, 20)
    axes[0].loglog(n, 1e-6 * n, "k:", lw=0.8, label="slope 1")
    axes[0].loglog(n, 1e-8 * n**3, "k--", lw=0.8, label="slope 3")
    axes[0].set(xlabel="cells N", ylabel="CPU s per attempted step", title="cost per step")
    axes[1].set(xlabel="cells N", ylabel="peak resident memory (MB)", title="memory")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_ylim(1e-5, 1e3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
