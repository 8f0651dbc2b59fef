"""A block sliding to rest on a plane under isotropic Coulomb friction, as 2-D disk friction
and as a 3-D frictional contact in the second-order (Coulomb) cone.

The model (`nivpjax.scenes.block_on_plane`), per unit mass, on a horizontal plane:

    disk:  p' = v,  v' in -mu g Sign(v),  Sign(v) = v/|v| (v != 0), the unit disk (v = 0);
    cone:  p' = v,  v' = (lam_t1, lam_t2, lam_n - g),
           K_mu  contains  lam = (lam_n, lam_t)   _|_   (v_n + mu |v_t|, v_t)  in  K_mu*,

the cone version resolving the normal direction too: lam lies in the Coulomb cone
|lam_t| <= mu lam_n, complementary to De Saxce's modified velocity, with lam as algebraic
states (multiplier "lam"). The disk version needs no extra states: friction is the proximal
map of mu g |v| on the velocity, and its force per unit mass is the velocity row of
`Solution.multipliers`.

Maths of the reference. The friction force mu g opposes the velocity, so the velocity keeps
its direction and its magnitude falls linearly:

    v(t) = v0 (1 - t/t*),   p(t) = v0_hat (|v0| t - mu g t^2 / 2),   t* = |v0| / (mu g),

the block stops after the distance |v0|^2 / (2 mu g) along v0 and stays there (the static
friction needed is zero). In the cone version lam_n = g throughout and
lam_t = -mu g v0_hat while sliding, 0 at rest. Up to t* the motion is quadratic in t, which
the scheme integrates exactly; the only error comes from locating the stop.

The script solves both versions with Bathe's scheme and a PID controller at three
tolerances (the tolerance is an input of one compiled function per version), prints the
errors and the compile and run times, and plots the path, the speed, the contact forces and
the step sizes.

Run:  python examples/block_on_plane.py      (writes examples/output/block_on_plane.png; ~25 s)
"""

import os


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import matplotlib  # noqa: E402
import numpy as np  # noqa: E402


matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from _references_mechanics import block_state, output_path, timed  # noqa: E402

import nivpjax as nj  # noqa: E402


jax.config.update("jax_enable_x64", True)

MU, G, V0, T1 = 0.3, 9.81, (2.0, 1.0), 1.2
SCENES = {
    cone: nj.scenes.block_on_plane(mu=MU, gravity=G, velocity=V0, cone=cone)
    for cone in (False, True)
}


def make_solver(scene):
    @eqx.filter_jit
    def solve(rtol, x0, args):
        controller = nj.PIDController(rtol=rtol, atol=1e-2 * rtol)
        return scene.solve(
            0.0,
            T1,
            x0,
            args,
            stepper=nj.Bathe(),
            controller=controller,
            max_steps=4000,
            throw=False,
        )

    return solve


def accuracy(scene, cone, sol):
    s = sol.trimmed()
    ts = np.asarray(s.ts)
    x, multipliers = scene.split(np.asarray(s.ys))
    nv = 3 if cone else 2
    p, v = x[:, :2], x[:, nv : nv + 2]
    p_ref, v_ref, t_stop = block_state(ts, V0, MU, G)
    k = np.flatnonzero(np.hypot(v[:, 0], v[:, 1]) > 1e-12)[-1] + 1  # first step at rest
    if cone:
        force = np.array(multipliers["lam"])  # (lam_n, lam_t1, lam_t2)
    else:
        mult = np.asarray(s.multipliers)[:, 2:]
        force = np.concatenate([np.full((ts.size, 1), G), mult], axis=1)
    force[0] = np.nan  # the initial state has no stage
    sliding = (ts > 0) & (ts < t_stop - 1e-3)
    friction = -MU * G * np.asarray(V0) / np.hypot(*V0)
    return dict(
        ts=ts,
        p=p,
        v=v,
        force=force,
        hs=np.asarray(s.hs),
        traj=np.max(np.maximum(np.abs(p - p_ref), np.abs(v - v_ref))),
        final=np.max(np.abs(p[-1] - p_ref[-1])),
        stop=(ts[k - 1], ts[k]),
        force_err=np.max(np.abs(force[sliding, 1:] - friction)),
        normal_err=np.max(np.abs(force[1:, 0] - G)),
        vertical=np.max(np.abs(x[:, [2, 5]])) if cone else 0.0,
    )


def main():
    speed = np.hypot(*V0)
    t_stop, distance = speed / (MU * G), speed**2 / (2 * MU * G)
    print(f"block on a plane: v0 = {V0}, mu = {MU}, g = {G}; Bathe + PID, t in [0, {T1}]")
    print(f"exact: stops at t* = {t_stop:.8f} after {distance:.8f} along v0")
    results = {}
    for cone in (False, True):
        scene, x0, args = SCENES[cone]
        solve = make_solver(scene)
        rtol = jnp.asarray(1e-6)
        sol, t_first = timed(solve, rtol, x0, args)
        sol, t_run = timed(solve, rtol, x0, args)
        name = "3-D contact, Coulomb cone" if cone else "2-D disk friction"
        print(f"\n{name}: compile {t_first - t_run:.2f} s, run {1e3 * t_run:.1f} ms (rtol 1e-6)")
        print(
            f"{'rtol':>7} {'steps':>6} {'rej':>4} {'run ms':>7} {'traj err':>9} "
            f"{'|p_end err|':>11} {'stop step':>20} {'friction err':>13} {'lam_n err':>10}"
        )
        for tol in (1e-4, 1e-6, 1e-8):
            s, elapsed = timed(solve, jnp.asarray(tol), x0, args)
            assert s.result == nj.RESULTS.successful
            a = accuracy(scene, cone, s)
            bracket = f"[{a['stop'][0]:.5f}, {a['stop'][1]:.5f}]"
            print(
                f"{tol:7.0e} {int(s.n_accepted):6d} {int(s.n_rejected):4d} {1e3 * elapsed:7.1f} "
                f"{a['traj']:9.2e} {a['final']:11.2e} {bracket:>20} {a['force_err']:13.1e} "
                f"{a['normal_err']:10.1e}"
            )
        results[cone] = accuracy(scene, cone, sol)
        if cone:
            print(
                f"max |p_z|, |v_z| (the block stays on the plane): {results[cone]['vertical']:.1e}"
            )

    tt = np.linspace(0, T1, 1000)
    p_ex, v_ex, _ = block_state(tt, V0, MU, G)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    axes[0, 0].plot(p_ex[:, 0], p_ex[:, 1], "k-", lw=1, label="exact")
    axes[1, 0].plot(tt, np.hypot(v_ex[:, 0], v_ex[:, 1]), "k-", lw=1, label="exact")
    axes[0, 1].plot(tt, np.where(tt < t_stop, MU * G, 0.0), "k-", lw=1, label="exact |lam_t|")
    axes[0, 1].axhline(G, color="grey", ls=":", lw=1, label="g (exact lam_n)")
    for cone, marker in ((False, "o"), (True, "x")):
        r = results[cone]
        label = "cone" if cone else "disk"
        axes[0, 0].plot(r["p"][:, 0], r["p"][:, 1], marker, ms=4, label=label)
        axes[1, 0].plot(r["ts"], np.hypot(r["v"][:, 0], r["v"][:, 1]), marker, ms=4, label=label)
        tangential = np.hypot(r["force"][:, 1], r["force"][:, 2])
        axes[0, 1].plot(r["ts"], tangential, marker, ms=4, label=f"{label} |lam_t|")
        if cone:
            axes[0, 1].plot(r["ts"], r["force"][:, 0], marker, ms=4, label="cone lam_n")
        axes[1, 1].semilogy(r["ts"][1:], r["hs"][1:], marker + "-", ms=4, label=label)
    for ax in axes.flat[1:]:
        ax.axvline(t_stop, color="grey", ls=":", lw=1)
    axes[0, 0].set_xlabel("p_x")
    axes[0, 0].set_ylabel("p_y")
    axes[0, 0].set_title("path: straight along v0")
    axes[1, 0].set_ylabel("speed |v|")
    axes[1, 0].set_xlabel("t")
    axes[0, 1].set_ylabel("contact force / m")
    axes[1, 1].set_ylabel("accepted step h")
    axes[1, 1].set_xlabel("t")
    for ax in axes.flat:
        ax.legend(fontsize=8)
    fig.suptitle(f"Block on a plane, mu = {MU}: stop at t* = {t_stop:.4f}")
    fig.tight_layout()
    path = output_path("block_on_plane.png")
    fig.savefig(path, dpi=120)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
