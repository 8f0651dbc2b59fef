"""A bouncing ball: impacts with Newton restitution, located by the step-size control, and
the Zeno accumulation of infinitely many impacts in finite time.

The model (`nivpjax.scenes.bouncing_ball`) is a ball on the floor,

    q' = v,   v' = -g   while q > 0,      v+ = -e v-   at impacts (q = 0, v- < 0),

written as a measure differential inclusion: the contact is a velocity-level constraint
(Moreau's sweeping process) solved inside every implicit stage, v = P(z) with
0 <= p  _|_  v + e v- >= 0. There is no event function: an impact missed inside a step shows
up as a penetration, which the controller treats as error and shrinks the step until the
impact is located to the tolerance.

Maths of the reference. Released from rest at height H, the ball first hits the floor at
t1 = sqrt(2H/g) with speed u1 = g t1; the k-th rebound leaves at e^k u1 and flies for
2 e^k u1 / g, reaching the apex height H e^(2k): apex heights fall by e^2 per bounce. The
flight times form a geometric series, so the impacts accumulate at

    t_inf = sqrt(2H/g) (1 + 2e/(1 - e))      (4.0637 s for H = 1, e = 0.8),

after which the ball rests on the floor. Between impacts the motion is a parabola, which
Bathe's scheme integrates exactly, so the numerical error comes only from the located
impacts.

The script solves with Bathe's scheme and a PID controller at three tolerances (the
tolerance is an input of one compiled function), prints the errors against the exact
solution (state at t = 3, trajectory, impact times, apex ratio e^2, time of coming to rest)
and the compile and run times, and plots the trajectory and the step sizes.

Run:  python examples/bouncing_ball.py      (writes examples/output/bouncing_ball.png; ~20 s)
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
from _references_mechanics import ball_impacts, ball_state, output_path, timed  # noqa: E402

import nivpjax as nj  # noqa: E402


jax.config.update("jax_enable_x64", True)

H, E, G = 1.0, 0.8, 9.81
scene, x0, args = nj.scenes.bouncing_ball(restitution=E, gravity=G, height=H)


@eqx.filter_jit
def solve(rtol, t1, x0, args):
    # rtol and t1 are traced: every tolerance and horizon reuses one executable.
    controller = nj.PIDController(rtol=rtol, atol=1e-2 * rtol)
    return scene.solve(
        0.0, t1, x0, args, stepper=nj.Bathe(), controller=controller, max_steps=8000, throw=False
    )


def accuracy(sol, t1):
    """Errors of a run against the exact solution."""
    s = sol.trimmed()
    ts, ys = np.asarray(s.ts), np.asarray(s.ys)
    t_imp, _, _ = ball_impacts(H, 0.0, E, G)
    q_ref, v_ref = ball_state(ts, H, 0.0, E, G)
    # Pointwise error away from the impacts: a located impact is off by less than the
    # tolerance in time, but the velocity jumps there.
    far = np.min(np.abs(ts[:, None] - t_imp[None, :]), axis=1) > 1e-4
    traj = np.max(np.maximum(np.abs(ys[far, 0] - q_ref[far]), np.abs(ys[far, 1] - v_ref[far])))
    jumps = np.flatnonzero(np.diff(ys[:, 1]) > 0)[:8]  # v grows only at impacts
    impact = np.max(np.abs(ts[jumps + 1] - t_imp[: jumps.size]))
    # Flight is exact, so q + v^2/(2g) right after an impact is the next apex height.
    apex = ys[jumps + 1, 0] + ys[jumps + 1, 1] ** 2 / (2 * G)
    ratio = np.max(np.abs(apex[1:] / apex[:-1] - E**2))
    q1, v1 = ball_state(np.array([t1]), H, 0.0, E, G)
    final = max(abs(float(sol.y_final[0]) - q1[0]), abs(float(sol.y_final[1]) - v1[0]))
    return dict(
        ts=ts, ys=ys, hs=np.asarray(s.hs), traj=traj, impact=impact, ratio=ratio, final=final
    )


def main():
    t1 = jnp.asarray(3.0)
    rtol = jnp.asarray(1e-6)
    sol, t_first = timed(solve, rtol, t1, x0, args)
    sol, t_run = timed(solve, rtol, t1, x0, args)
    print(f"bouncing ball: H = {H}, e = {E}, g = {G}; Bathe + PID, t in [0, 3]")
    print(f"compile {t_first - t_run:.2f} s, run {1e3 * t_run:.1f} ms (rtol 1e-6)")
    print(
        f"{'rtol':>7} {'steps':>6} {'rej':>5} {'run ms':>7} {'|y(3) err|':>11} "
        f"{'traj err':>9} {'impact t err':>13} {'|apex ratio - e^2|':>19}"
    )
    for tol in (1e-4, 1e-6, 1e-8):
        s, elapsed = timed(solve, jnp.asarray(tol), t1, x0, args)
        assert s.result == nj.RESULTS.successful
        a = accuracy(s, 3.0)
        print(
            f"{tol:7.0e} {int(s.n_accepted):6d} {int(s.n_rejected):5d} {1e3 * elapsed:7.1f} "
            f"{a['final']:11.2e} {a['traj']:9.2e} {a['impact']:13.2e} {a['ratio']:19.2e}"
        )

    # Past the accumulation point.
    _, _, t_inf = ball_impacts(H, 0.0, E, G)
    z, elapsed = timed(solve, rtol, jnp.asarray(4.3), x0, args)
    zs = z.trimmed()
    ts, ys = np.asarray(zs.ts), np.asarray(zs.ys)
    rest = (np.abs(ys[:, 0]) < 1e-9) & (np.abs(ys[:, 1]) < 1e-6)
    t_rest = ts[np.argmax(rest)]
    print(
        f"\nZeno: exact t_inf = {t_inf:.6f}; the ball is at rest (|q| < 1e-9, |v| < 1e-6) "
        f"from t = {t_rest:.6f} (error {t_rest - t_inf:+.1e}); {int(z.n_accepted)} steps, "
        f"{int(z.n_rejected)} rejected, {1e3 * elapsed:.0f} ms"
    )
    after = ts > t_inf + 1e-3
    print(
        f"after t_inf: max |q| = {np.max(np.abs(ys[after, 0]), initial=0):.1e}, "
        f"max |v| = {np.max(np.abs(ys[after, 1]), initial=0):.1e}; run ended at "
        f"t = {float(z.t_final):.4f}: {nj.RESULTS[z.result]}"
    )
    if z.result != nj.RESULTS.successful:
        print(
            "  (known limitation: a resting contact left with a round-off separating "
            "velocity caps the step size; see tests/test_scenes_mechanics.py)"
        )

    a = accuracy(sol, 3.0)
    tt = np.linspace(0, 4.3, 4000)
    q_ex, v_ex = ball_state(tt, H, 0.0, E, G)
    fig, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    axes[0].plot(tt, q_ex, "k-", lw=1, label="exact")
    axes[0].plot(ts, ys[:, 0], "o", ms=2, label="nivpjax (Bathe, rtol 1e-6)")
    axes[0].axvline(t_inf, color="grey", ls=":", lw=1, label="t_inf")
    axes[0].set_ylabel("height q")
    axes[0].legend()
    axes[1].plot(tt, v_ex, "k-", lw=1)
    axes[1].plot(ts, ys[:, 1], "o", ms=2)
    axes[1].set_ylabel("velocity v")
    axes[2].semilogy(ts[1:], np.asarray(zs.hs)[1:], ".-", ms=2)
    axes[2].axvline(t_inf, color="grey", ls=":", lw=1)
    axes[2].set_ylabel("accepted step h")
    axes[2].set_xlabel("t")
    fig.suptitle(
        f"Bouncing ball, e = {E}: impacts located to {a['impact']:.0e} s, Zeno at t = {t_inf:.3f}"
    )
    fig.tight_layout()
    path = output_path("bouncing_ball.png")
    fig.savefig(path, dpi=120)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
