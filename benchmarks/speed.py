"""Engine speed after compilation: plain-call overhead, repeated compat calls with rebuilt
callbacks, and batch throughput of the bouncing ball, old path (`jax.jit(jax.vmap(...))`)
against `Scene.sweep` / `nj.solve_batched` (ordered by restitution, chunked).

Run:  python -m benchmarks.speed [--batch 10000] [--chunk 1000]

Times are best-of-repeats wall seconds; with other jobs on the cores, compare ratios
measured in the same run.
"""

import argparse
import os
import time


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import nivpjax as nj  # noqa: E402
from nivpjax._solve import _solve_jit  # noqa: E402

from . import _common  # noqa: E402, F401  (float64)


def best(fn, number=20, repeats=5):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(number):
            jax.block_until_ready(fn())
        times.append((time.perf_counter() - t) / number)
    return min(times)


def overhead():
    """A plain `nj.solve` call against the compiled program it runs (same arguments)."""

    def f(t, y, args):
        return -y

    y0 = jnp.array([1.0, 2.0])
    solve = lambda: nj.solve(f, 0.0, 1.0, y0, max_steps=64)
    solve()
    box = {}
    original = _solve_jit._call
    _solve_jit._call = lambda call: box.setdefault("call", call) and original(call)
    solve()
    _solve_jit._call = original
    call = box["call"]
    program = _solve_jit._program(call.key)
    dynamic = [jnp.asarray(x) for x in call.dynamic]
    t_solve = best(solve, number=50)
    t_program = best(lambda: program(dynamic), number=50)
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
    t_old = best(lambda: old(jnp.asarray(es)), number=1, repeats=2)
    acc_old = int(np.sum(np.asarray(sol_old.n_accepted)))
    waste_old = nj.lockstep_waste(sol_old)

    axes = {**{k: None for k in args}, "e": 0}
    sweep = lambda: scene.sweep(
        0.0, 1.5, x0, {**args, "e": es}, args_axes=axes, cost=es, chunk_size=chunk, **kw
    )
    t = time.perf_counter()
    sol_new = jax.block_until_ready(sweep())
    c_new = time.perf_counter() - t
    t_new = best(sweep, number=1, repeats=2)
    acc_new = int(np.sum(np.asarray(sol_new.n_accepted)))
    waste_new = nj.lockstep_waste(sol_new, chunk_size=chunk, cost=es)
    same = np.array_equal(np.asarray(sol_old.n_accepted), np.asarray(sol_new.n_accepted))
    return dict(
        old=(t_old, acc_old / t_old, waste_old, c_old),
        new=(t_new, acc_new / t_new, waste_new, c_new),
        same_steps=same,
        ok=int(np.sum(np.asarray(sol_new.result._value) == 0)),
    )


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
