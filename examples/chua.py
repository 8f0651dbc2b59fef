"""Chua's circuit: the double-scroll attractor from a piecewise-linear diode.

The model (`nivpjax.scenes.chua`) is the dimensionless Chua oscillator

    x' = alpha (y - x - g(x)),   y' = x - y + z,   z' = -beta y,
    g(x) = m0 x + (m1 - m0) sat(x),   sat(x) = clip(x, -1, 1),

with alpha = 15.6, beta = 28, m0 = -1.143, m1 = -0.714: three linear regions (|x| < 1,
x > 1, x < -1) glued continuously, with kinks of the vector field on the planes x = +-1.
nivpjax carries sat(x) as a multiplier s in [-1, 1] defined by the variational inequality
<s - x, eta - s> >= 0 for all eta in [-1, 1] (the projection s = clip(x)), solved with the
state at each implicit stage: the kink needs no event detection or smoothing.

Reference. On each linear region the field is linear, so DOP853 at rtol 1e-13 integrates a
smooth ODE up to a terminal event on x = +-1 and restarts on the kink; no reference step
straddles a kink. The flow is chaotic (nearby trajectories separate exponentially), so
pointwise comparison is meaningful only over a short horizon: the script compares on
[0, 10] (eleven kink crossings; a 1e-9 perturbation of x0 grows to 3e-8 there), at two
tolerances with one compiled solver (t1 and rtol are inputs), then runs to t = 150 to draw
the attractor and shows how the difference to the reference grows past the horizon.

Run:  python examples/chua.py      (writes examples/output/chua.png; about 20 s)
"""

import os


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import matplotlib  # noqa: E402
import numpy as np  # noqa: E402


matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from _references_switching import (  # noqa: E402
    chua_reference,
    output_path,
    run_timed,
    timed_solve,
)

import nivpjax as nj  # noqa: E402


jax.config.update("jax_enable_x64", True)

scene, x0, args = nj.scenes.chua()
P = {k: float(v) for k, v in args.items()}
HORIZON, T_LONG = 10.0, 150.0


def solve(t1, rtol, x0, args):
    controller = nj.PIDController(rtol=rtol, atol=1e-2 * rtol)
    return scene.solve(0.0, t1, x0, args, controller=controller, max_steps=40_000, throw=False)


def unpack(sol):
    sol = sol.trimmed()
    x, m = scene.split(sol.ys)
    return np.asarray(sol.ts), np.asarray(x), np.asarray(m["sat"][:, 0]), np.asarray(sol.hs), sol


def main():
    inputs = (jnp.asarray(HORIZON), jnp.asarray(1e-6), x0, args)
    compiled, sol, t_compile, t_run = timed_solve(solve, *inputs)
    print(f"Chua's circuit {P}, x0 = {np.asarray(x0)}")
    print(f"compile {t_compile:.2f} s")
    print(
        f"{'rtol':>7} {'t1':>5} {'steps':>6} {'rej':>4} {'run ms':>7} "
        f"{'max|x - ref| on [0, 10]':>24} {'kink crossings':>15} {'|sat - clip(x)|':>16}"
    )
    runs = {1e-6: (sol, t_run)}
    runs[1e-8] = run_timed(compiled, jnp.asarray(HORIZON), jnp.asarray(1e-8), x0, args)
    for tol, (s, elapsed) in runs.items():
        assert s.result == nj.RESULTS.successful
        ts, x, sat, hs, s = unpack(s)
        ref, kinks = chua_reference(np.asarray(x0), ts, **P)
        g = np.abs(x[:, 0]) - 1
        n_kinks = np.count_nonzero((g[1:] > 0) != (g[:-1] > 0))
        sat_error = np.max(np.abs(sat[1:] - np.clip(x[1:, 0], -1, 1)))
        print(
            f"{tol:7.0e} {HORIZON:5.0f} {int(s.n_accepted):6d} {int(s.n_rejected):4d} "
            f"{1e3 * elapsed:7.1f} {np.max(np.abs(x - ref)):24.2e} "
            f"{f'{n_kinks} (ref {kinks.size})':>15} {sat_error:16.1e}"
        )

    long, elapsed = run_timed(compiled, jnp.asarray(T_LONG), jnp.asarray(1e-6), x0, args)
    assert long.result == nj.RESULTS.successful
    ts, x, sat, hs, long = unpack(long)
    print(
        f"{1e-6:7.0e} {T_LONG:5.0f} {int(long.n_accepted):6d} {int(long.n_rejected):4d} "
        f"{1e3 * elapsed:7.1f}   (attractor run)"
    )
    early = ts <= 40.0
    ref, _ = chua_reference(np.asarray(x0), ts[early], **P)
    gap = np.max(np.abs(x[early] - ref), axis=1)
    for t in (10, 20, 30, 40):
        print(f"  |x - ref| at t <= {t}: {np.max(gap[ts[early] <= t]):.1e}")

    fig = plt.figure(figsize=(11, 8))
    ax = fig.add_subplot(2, 2, 1, projection="3d")
    ax.plot(x[:, 0], x[:, 1], x[:, 2], lw=0.3)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    ax.set_title(f"double scroll, t in [0, {T_LONG:g}] (rtol 1e-6)")
    ax = fig.add_subplot(2, 2, 2)
    ax.plot(x[:, 0], x[:, 2], lw=0.3)
    ax.axvline(1, color="grey", ls=":", lw=1)
    ax.axvline(-1, color="grey", ls=":", lw=1)
    ax.set_xlabel("x (kinks of g at x = +-1)")
    ax.set_ylabel("z")
    ax.set_title("projection on (x, z)")
    ax = fig.add_subplot(2, 2, 3)
    ax.semilogy(ts[early], gap + 1e-16)
    ax.axvline(HORIZON, color="grey", ls=":", lw=1)
    ax.set_xlabel("t")
    ax.set_ylabel("max |x - x_ref|")
    ax.set_title("difference to the reference: chaos amplifies it")
    ax = fig.add_subplot(2, 2, 4)
    ax.semilogy(ts[1:], hs[1:], lw=0.5)
    ax.set_xlabel("t")
    ax.set_ylabel("accepted step h")
    ax.set_title("step sizes")
    fig.tight_layout()
    path = output_path("chua.png")
    fig.savefig(path, dpi=120)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
