"""Super-twisting sliding-mode control: finite-time convergence without chattering.

The model (`nivpjax.scenes.super_twisting`) is a double integrator with a bounded
disturbance d(t) = 0.3 sin 5t, driven by the super-twisting algorithm on the sliding variable
sigma = x2 + c x1:

    x1' = x2,   x2' = u + d(t),   u = -k1 sqrt|sigma| w + nu,   nu' = -k2 w,   w in sign(sigma),

with k1 = 1.5 sqrt(L), k2 = 1.1 L (L = 1.5 bounds |d'|). sigma and sigma' are driven to 0 in
finite time; on sigma = 0 the discontinuous w takes its Filippov (equivalent-control) value,
a smooth function of time, so the control u = nu is continuous: no chattering. Then
x2 = -c x1 and x1 decays like exp(-ct), while nu cancels the disturbance: nu = -d(t) - c x2.

nivpjax carries w as a multiplier in [-1, 1] solved implicitly with the state at every stage
(sqrt|sigma| has a capped derivative so Newton's Jacobian stays finite on sigma = 0).

Reference. Before sliding, sigma changes sign transversally a number of times (the
"twisting" around the origin of the (sigma, sigma') plane) and the crossings accumulate at
the reaching time T*. Between crossings w = sign(sigma) is constant and the ODE is smooth:
the reference integrates each piece with DOP853 at rtol 1e-12 up to the next crossing (a
terminal event), until two crossings are 1e-9 apart. After T* the sliding motion is known in
closed form (above). The script compares the whole trajectory with it, reports the reaching
time, |sigma| in sliding, how closely w follows the equivalent control
w_eq = -nu'/k2 = (d' - c^2 x2)/k2, and plots sigma (log scale), nu against -d, w against
w_eq and the step sizes.

Run:  python examples/super_twisting.py      (writes examples/output/super_twisting.png;
about 20 s)
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
    run_timed,
    st_disturbance,
    super_twisting_reference,
    timed_solve,
)

import nivpjax as nj  # noqa: E402


jax.config.update("jax_enable_x64", True)

T1 = 10.0
scene, x0, args = nj.scenes.super_twisting()
K1, K2, C = (float(args[k]) for k in ("k1", "k2", "c"))


def solve(rtol, x0, args):
    controller = nj.PIDController(rtol=rtol, atol=1e-2 * rtol)
    return scene.solve(0.0, T1, x0, args, controller=controller, max_steps=8192, throw=False)


def analyse(sol):
    sol = sol.trimmed()
    ts = np.asarray(sol.ts)
    x, m = scene.split(sol.ys)
    x, w = np.asarray(x), np.asarray(m["w"][:, 0])
    ref, crossings, T = super_twisting_reference(np.asarray(x0), K1, K2, C, ts)
    sigma = x[:, 1] + C * x[:, 0]
    k = np.flatnonzero(np.abs(sigma) > 1e-14)[-1] + 1  # sliding from ts[k] on
    d, dd = st_disturbance(ts)
    w_eq = (dd - C**2 * x[:, 1]) / K2
    before = ts < T
    return dict(
        ts=ts,
        x=x,
        w=w,
        w_eq=w_eq,
        sigma=sigma,
        hs=np.asarray(sol.hs),
        T=T,
        crossings=crossings,
        k=k,
        reach_error=ts[k] - T,
        err_reaching=np.max(np.abs(x[before] - ref[before]), axis=0),
        err_sliding=np.max(np.abs(x[k:] - ref[k:])),
        sigma_sliding=np.max(np.abs(sigma[k:])),
        # From 1e-3 after landing (the landing steps' w mix +-1 and the sliding value).
        w_dev=np.max(np.abs(w - w_eq)[ts > ts[k] + 1e-3]),
        nu_plus_d=abs(x[-1, 2] + d[-1]),
        steps=(int(sol.n_accepted), int(sol.n_rejected)),
    )


def main():
    compiled, sol, t_compile, t_run = timed_solve(solve, jnp.asarray(1e-6), x0, args)
    assert sol.result == nj.RESULTS.successful
    r = analyse(sol)
    print(f"super-twisting, k1 = {K1:.4f}, k2 = {K2:.4f}, c = {C}, x0 = {np.asarray(x0)}")
    print(f"reference: sigma crosses 0 at t = {np.array2string(r['crossings'][:5], precision=4)}")
    print(f"           ... accumulating at the reaching time T* = {r['T']:.8f}")
    print(f"compile {t_compile:.2f} s, run {1e3 * t_run:.1f} ms (rtol 1e-6)")
    print(
        f"{'rtol':>7} {'steps':>6} {'rej':>4} {'run ms':>7} {'T_num - T*':>11} "
        f"{'reach err x1,x2,nu':>28} {'slide err':>10} {'|sigma|':>8} {'|w-w_eq|':>9} "
        f"{'|nu+d| t=10':>11}"
    )
    for tol in (1e-4, 1e-6, 1e-8):
        s, elapsed = run_timed(compiled, jnp.asarray(tol), x0, args)
        assert s.result == nj.RESULTS.successful
        q = analyse(s)
        e = q["err_reaching"]
        print(
            f"{tol:7.0e} {q['steps'][0]:6d} {q['steps'][1]:4d} {1e3 * elapsed:7.1f} "
            f"{q['reach_error']:11.2e} {e[0]:9.1e},{e[1]:8.1e},{e[2]:8.1e} "
            f"{q['err_sliding']:10.1e} {q['sigma_sliding']:8.0e} {q['w_dev']:9.3f} "
            f"{q['nu_plus_d']:11.1e}"
        )
    print(
        "T_num: the first accepted time after which |sigma| < 1e-14; |w - w_eq|: the largest\n"
        "gap between the computed selection and the smooth equivalent control from T_num + 1e-3\n"
        "(the one or two steps that land on sigma = 0 mix the twisting and the sliding value)."
    )

    ts, x = r["ts"], r["x"]
    tt = np.linspace(0, T1, 4000)
    ref, _, T = super_twisting_reference(np.asarray(x0), K1, K2, C, tt)
    fig, axes = plt.subplots(4, 1, figsize=(7, 10), sharex=True)
    axes[0].semilogy(tt, np.abs(ref[:, 1] + C * ref[:, 0]) + 1e-20, "k-", lw=1, label="reference")
    axes[0].semilogy(ts, np.abs(r["sigma"]) + 1e-20, "o", ms=2, label="nivpjax (rtol 1e-6)")
    axes[0].axvline(T, color="grey", ls=":", lw=1)
    axes[0].set_ylim(1e-20, 1)
    axes[0].set_ylabel("|sigma| (+1e-20)")
    axes[0].legend(loc="upper right")
    axes[1].plot(tt, ref[:, 2], "k-", lw=1, label="nu, reference")
    axes[1].plot(ts, x[:, 2], "o", ms=2, label="nu, nivpjax")
    axes[1].plot(tt, -st_disturbance(tt)[0], "r--", lw=1, label="-d(t)")
    axes[1].set_ylabel("nu")
    axes[1].legend(loc="upper right", fontsize=8, framealpha=0.9)
    slide = tt >= T
    w_eq_ref = (st_disturbance(tt[slide])[1] - C**2 * ref[slide, 1]) / K2
    axes[2].plot(tt[slide], w_eq_ref, "k-", lw=1, label="w_eq = (d' - c^2 x2)/k2, reference")
    axes[2].plot(ts[1:], r["w"][1:], "o", ms=2, label="multiplier w, nivpjax")
    axes[2].set_ylabel("w")
    axes[2].set_ylim(-1.15, 1.7)
    axes[2].legend(loc="upper right", ncol=2, fontsize=8, framealpha=0.9)
    axes[3].semilogy(ts[1:], r["hs"][1:], ".-", ms=3)
    axes[3].axvline(T, color="grey", ls=":", lw=1)
    axes[3].set_ylabel("accepted step h")
    axes[3].set_xlabel("t")
    fig.suptitle("Super-twisting: twisting, finite-time reaching, sliding without chattering")
    fig.tight_layout()
    path = output_path("super_twisting.png")
    fig.savefig(path, dpi=120)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
