"""Relay feedback with a disturbance: finite-time reaching and Filippov sliding.

The model (`nivpjax.scenes.relay`) is the differential inclusion

    x' = -sign(x) + d(t),   d(t) = a sin(2 pi f t),   |a| < 1,

with sign(0) = [-1, 1] (Filippov's convexification). nivpjax carries the relay output as a
multiplier w in [-1, 1] next to the state; every implicit stage solves the variational
inequality w = P_[-1,1](w + rho x), i.e. w = sign(x) when x != 0 and any w in [-1, 1] that
keeps x on the surface otherwise. No event detection, no regularisation of sign.

Maths of the reference. While x > 0, w = 1 and x' = -1 + d(t) <= -(1 - |a|) < 0, so

    x(t) = x0 - t + a (1 - cos 2 pi f t) / (2 pi f)

reaches 0 at a unique time T (root found by Brent's method). From then on |d| < 1 keeps
the state on x = 0 (sliding mode) and the Filippov selection is the equivalent control that
cancels the disturbance: w(t) = d(t). The script checks the numerical reaching time, the
free motion, x = 0 and w = d(t) in sliding, at three tolerances with one compiled solver
(the tolerance is an input of the compiled function), and plots the trajectory, the
selection and the step sizes (which grow by orders of magnitude once the state slides: the
sliding solution x = 0 is exact for the scheme).

Run:  python examples/relay.py      (writes examples/output/relay.png; about 15 s)
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
    output_path,
    relay_exact,
    run_timed,
    timed_solve,
)

import nivpjax as nj  # noqa: E402


jax.config.update("jax_enable_x64", True)

A, F, X0, T1 = 0.5, 1.0, 0.5, 3.0
scene, x0, args = nj.scenes.relay(amplitude=A, frequency=F, x0=X0)


def solve(rtol, x0, args):
    controller = nj.PIDController(rtol=rtol, atol=1e-3 * rtol)
    return scene.solve(0.0, T1, x0, args, controller=controller, max_steps=4096, throw=False)


def report(sol):
    sol = sol.trimmed()
    ts = np.asarray(sol.ts)
    x, m = scene.split(sol.ys)
    x, w = np.asarray(x[:, 0]), np.asarray(m["w"][:, 0])
    x_ref, _, T = relay_exact(ts, A, F, X0)
    k = np.flatnonzero(np.abs(x) < 1e-15)[0]  # first accepted state on the surface
    # Numerical reaching time: first-order extrapolation from the last state before it.
    t_reach = ts[k - 1] + x[k - 1] / (1 - A * np.sin(2 * np.pi * F * ts[k - 1]))
    before, sliding = ts < T, np.arange(ts.size) > k
    return dict(
        ts=ts,
        x=x,
        w=w,
        hs=np.asarray(sol.hs),
        T=T,
        reach_error=t_reach - T,
        free_error=np.max(np.abs(x[before] - x_ref[before])),
        slide_x=np.max(np.abs(x[ts > T])),
        slide_w=np.max(np.abs(w[sliding] - A * np.sin(2 * np.pi * F * ts[sliding]))),
        steps=(int(sol.n_accepted), int(sol.n_rejected)),
    )


def main():
    rtol = jnp.asarray(1e-6)
    compiled, sol, t_compile, t_run = timed_solve(solve, rtol, x0, args)
    assert sol.result == nj.RESULTS.successful
    r = report(sol)
    print(f"relay x' = -sign(x) + {A} sin(2 pi {F} t), x0 = {X0}, t in [0, {T1}]")
    print(f"exact reaching time T = {r['T']:.12f}")
    print(f"compile {t_compile:.2f} s, run {1e3 * t_run:.1f} ms (rtol 1e-6)")
    print(
        f"{'rtol':>7} {'steps':>6} {'rej':>4} {'run ms':>7} {'|T_num - T|':>12} "
        f"{'free |x err|':>13} {'slide |x|':>10} {'slide |w-d|':>12}"
    )
    for tol in (1e-4, 1e-6, 1e-8):
        s, elapsed = run_timed(compiled, jnp.asarray(tol), x0, args)
        assert s.result == nj.RESULTS.successful
        q = report(s)
        print(
            f"{tol:7.0e} {q['steps'][0]:6d} {q['steps'][1]:4d} {1e3 * elapsed:7.1f} "
            f"{abs(q['reach_error']):12.2e} {q['free_error']:13.2e} {q['slide_x']:10.1e} "
            f"{q['slide_w']:12.1e}"
        )

    tt = np.linspace(0, T1, 2000)
    x_exact, w_exact, T = relay_exact(tt, A, F, X0)
    fig, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    axes[0].plot(tt, x_exact, "k-", lw=1, label="exact")
    axes[0].plot(r["ts"], r["x"], "o", ms=3, label="nivpjax (Bathe, rtol 1e-6)")
    axes[0].axvline(T, color="grey", ls=":", lw=1)
    axes[0].set_ylabel("x")
    axes[0].legend()
    axes[1].plot(tt, w_exact, "k-", lw=1, label="exact selection (1, then d(t))")
    axes[1].plot(r["ts"][1:], r["w"][1:], "o", ms=3, label="multiplier w")
    axes[1].set_ylabel("w")
    axes[1].legend()
    axes[2].semilogy(r["ts"][1:], r["hs"][1:], ".-")
    axes[2].axvline(T, color="grey", ls=":", lw=1)
    axes[2].set_ylabel("accepted step h")
    axes[2].set_xlabel("t")
    fig.suptitle("Relay with disturbance: reaching, then Filippov sliding")
    fig.tight_layout()
    path = output_path("relay.png")
    fig.savefig(path, dpi=120)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
