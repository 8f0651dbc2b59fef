"""Engine speed after compilation: plain-call overhead, repeated compat calls with rebuilt
callbacks (a smooth model, and the reference's own example scripts against the reference),
the marginal cost of an adaptive attempt on the ball against diffrax `Kvaerno5`
on a penalty-regularised ball, and batch throughput of the bouncing ball, old path
(`jax.jit(jax.vmap(...))`) against `Scene.sweep` / `nj.solve_batched` (ordered by
restitution, chunked).

Run:  python -m benchmarks.speed [--batch 10000] [--chunk 1000]

Times are best-of-repeats wall seconds; with other jobs on the cores, compare ratios
measured in the same run.
"""

import argparse
import os
import time


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import diffrax  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import nivpjax as nj  # noqa: E402
from nivpjax._solve import _solve_jit  # noqa: E402

from . import _common  # noqa: E402, F401  (float64)
from .regularised import _ball as penalty_ball  # noqa: E402


def best(fn, number=20, repeats=5):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(number):
            jax.block_until_ready(fn())
        times.append((time.perf_counter() - t) / number)
    return min(times)


def _program(call_solve):
    """The solution of `call_solve()` and its compiled program as a function of nothing
    (the arguments `nj.solve` passed it), without the Python-side work of a call."""
    box = {}
    original = _solve_jit._call

    def spy(call):
        box["call"] = call
        return original(call)

    _solve_jit._call = spy
    try:
        sol = call_solve()
    finally:
        _solve_jit._call = original
    call = box["call"]
    program = _solve_jit._program(call.key)
    dynamic = [jnp.asarray(x) for x in call.dynamic]
    return sol, lambda: program(dynamic)


def overhead():
    """A plain `nj.solve` call against the compiled program it runs (same arguments)."""

    def f(t, y, args):
        return -y

    y0 = jnp.array([1.0, 2.0])
    solve = lambda: nj.solve(f, 0.0, 1.0, y0, max_steps=64)
    solve()
    _, program = _program(solve)
    t_solve = best(solve, number=50)
    t_program = best(program, number=50)
    return t_solve, t_program


def compat_repeated(calls=5):
    """A reference-style script: callbacks rebuilt inside a function, called in a loop."""
    from nivpjax.compat import solve_ivp_ns

    def run(k):
        def fun(t, y):
            return jnp.array([y[1], -k * y[0] - 0.1 * y[1]])

        return solve_ivp_ns(fun, (0.0, 2.0), [1.0, 0.0], method="composite", h0=1e-2)

    t = time.perf_counter()
    run(1.0)
    first = time.perf_counter() - t
    t = time.perf_counter()
    for i in range(calls):
        run(2.0 + i)
    return first, (time.perf_counter() - t) / calls


def compat_scripts(calls=5, rtol=1e-3):
    """The reference's own example scripts (its notebook settings for the ball, trapezoidal
    + VI, and the Coulomb slider, composite + VI; `benchmarks.bench_reference`), each call
    rebuilding its callbacks, through `nivpjax.compat.solve_ivp_ns` and through the
    reference: (name, reference s per call, compat first call s, compat s per later call)."""
    import contextlib
    import io

    import solve_nivp

    from nivpjax.compat import solve_ivp_ns

    from .bench_reference import _ref_ball, _ref_slider

    rows = []
    for name, script in (("ball", _ref_ball), ("slider", _ref_slider)):

        def ours(script=script):
            kwargs = script("VI", xp=jnp)
            return solve_ivp_ns(**kwargs, rtol=rtol, atol=1e-3 * rtol)

        def reference(script=script):
            with contextlib.redirect_stdout(io.StringIO()):  # it prints on some paths
                return solve_nivp.solve_ivp_ns(**script("VI"), rtol=rtol, atol=1e-3 * rtol)

        t = time.perf_counter()
        ours()
        first = time.perf_counter() - t
        t = time.perf_counter()
        for _ in range(calls):
            ours()
        again = (time.perf_counter() - t) / calls
        ref = best(reference, number=1, repeats=3)
        rows.append((name, ref, first, again))
    return rows


def _ball_exact_steps(sol):
    return np.asarray(sol.n_accepted), np.asarray(sol.n_accepted + sol.n_rejected)


def batch(size, chunk, rtol=1e-3):
    scene, x0, args = nj.scenes.bouncing_ball()
    es = np.linspace(0.8, 0.95, size)
    rng = np.random.default_rng(0)
    es = rng.permutation(es)
    controller = nj.PIDController(rtol=rtol, atol=rtol * 1e-3)
    kw = dict(controller=controller, max_steps=1024, throw=False, adjoint="forward")

    def one(e):
        return scene.solve(0.0, 1.5, x0, {**args, "e": e}, **kw)

    old = jax.jit(jax.vmap(one))
    t = time.perf_counter()
    sol_old = jax.block_until_ready(old(jnp.asarray(es)))
    c_old = time.perf_counter() - t
    t_old = best(lambda: old(jnp.asarray(es)), number=1, repeats=5)
    acc_old = int(np.sum(np.asarray(sol_old.n_accepted)))
    waste_old = nj.lockstep_waste(sol_old)

    axes = {**{k: None for k in args}, "e": 0}
    sweep = lambda: scene.sweep(
        0.0, 1.5, x0, {**args, "e": es}, args_axes=axes, cost=es, chunk_size=chunk, **kw
    )
    t = time.perf_counter()
    sol_new = jax.block_until_ready(sweep())
    c_new = time.perf_counter() - t
    t_new = best(sweep, number=1, repeats=5)
    acc_new = int(np.sum(np.asarray(sol_new.n_accepted)))
    waste_new = nj.lockstep_waste(sol_new, chunk_size=chunk, cost=es)
    same = np.array_equal(np.asarray(sol_old.n_accepted), np.asarray(sol_new.n_accepted))
    return dict(
        old=(t_old, acc_old / t_old, waste_old, c_old),
        new=(t_new, acc_new / t_new, waste_new, c_new),
        same_steps=same,
        ok=int(np.sum(np.asarray(sol_new.result._value) == 0)),
    )


def _penalty_ball(restitution, k=1e4, g=9.81):
    params = {"e": restitution, "g": g}
    f = lambda t, x, args: penalty_ball(t, x, params, k, jnp)  # noqa: E731

    @jax.jit
    def run(t1, rtol):
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(f),
            diffrax.Kvaerno5(),
            0.0,
            t1,
            None,
            jnp.array([1.0, 0.0]),
            stepsize_controller=diffrax.PIDController(rtol=rtol, atol=1e-3 * rtol),
            max_steps=16384,
            throw=False,
        )
        return sol.ys, sol.stats["num_steps"]

    return run


def attempt_cost(restitution=0.95, horizons=(0.5, 8.0), rtol=1e-4):
    """The marginal cost of an adaptive attempt: the difference of the compiled runs over
    two horizons divided by the difference of their attempts, so that what a call costs
    once (dispatch, buffers, the initial step, the result) cancels; nivpjax's compiled
    program is timed without `nj.solve`'s Python-side work, diffrax's jitted function
    with its dispatch. nivpjax's default
    solver on the ball (output buffers of 1024 rows) against `Kvaerno5` on the
    penalty-regularised ball (k = 1e4), each best of 50 calls per horizon."""
    scene, x0, args = nj.scenes.bouncing_ball(restitution)
    controller = nj.PIDController(rtol=rtol, atol=1e-3 * rtol)
    kvaerno = _penalty_ball(restitution)
    rows = {}
    for name in ("nivpjax", "Kvaerno5"):
        points = []
        for t1 in horizons:
            if name == "nivpjax":
                sol, run = _program(
                    lambda t1=t1: scene.solve(
                        0.0, t1, x0, args, controller=controller, max_steps=1024
                    )
                )
                attempts = int(sol.n_accepted + sol.n_rejected)
            else:
                run = lambda t1=t1: kvaerno(t1, rtol)
                attempts = int(run()[1])
            points.append((attempts, best(run, number=50, repeats=3)))
        (a0, t0), (a1, t1_) = points
        rows[name] = (a0, t0, a1, t1_, (t1_ - t0) / (a1 - a0))
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=10_000)
    parser.add_argument("--chunk", type=int, default=1000)
    parser.add_argument("--skip-batch", action="store_true")
    opts = parser.parse_args(argv)
    t_solve, t_program = overhead()
    print(
        f"plain call: nj.solve {1e3 * t_solve:.3f} ms, its compiled program "
        f"{1e3 * t_program:.3f} ms: overhead {1e3 * (t_solve - t_program):.3f} ms"
    )
    first, again = compat_repeated()
    print(
        f"compat solve_ivp_ns, callbacks rebuilt per call: first {first:.2f} s, "
        f"then {1e3 * again:.1f} ms per call ({first / again:.0f}x)"
    )
    print("\nthe reference's example scripts, callbacks rebuilt per call, rtol 1e-3:")
    print("| script | reference s per call | compat first call s | compat ms per call | ratio |")
    print("|---|---:|---:|---:|---:|")
    for name, ref, first, again in compat_scripts():
        print(f"| {name} | {ref:.2f} | {first:.2f} | {1e3 * again:.1f} | {ref / again:.0f}x |")
    rows = attempt_cost()
    print("\nmarginal cost of an adaptive attempt, ball (e = 0.95, rtol 1e-4, t1 = 0.5 and 8):")
    print("| solver | attempts, t1 = 0.5 | call µs | attempts, t1 = 8 | call µs | µs per attempt |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, (a0, t0, a1, t1, marginal) in rows.items():
        print(f"| {name} | {a0} | {1e6 * t0:.1f} | {a1} | {1e6 * t1:.1f} | {1e6 * marginal:.2f} |")
    if opts.skip_batch:
        return
    r = batch(opts.batch, opts.chunk)
    print(f"\n{opts.batch} bouncing balls, rtol 1e-3, e in [0.8, 0.95] (shuffled):")
    print("| path | run s | accepted step-trajectories/s | waste | first call s |")
    print("|---|---:|---:|---:|---:|")
    for name, key in (("jit(vmap(scene.solve))", "old"), ("scene.sweep, sorted, chunked", "new")):
        t, rate, waste, c = r[key]
        print(f"| {name} | {t:.2f} | {rate:.3g} | {100 * waste:.0f}% | {c:.1f} |")
    print(
        f"speed-up {r['new'][1] / r['old'][1]:.2f}x; same step counts per member: "
        f"{r['same_steps']}; members succeeded: {r['ok']}/{opts.batch}"
    )


if __name__ == "__main__":
    main()
