"""A spring slider with Coulomb friction: slip, stick, and driven stick-slip.

The model (`nivpjax.scenes.spring_slider`) is a block of mass m on a spring of stiffness k
whose far end moves at the drive velocity V, with viscous damping c and Coulomb friction
under the normal force N:

    m s'' = k (V t - s) - c s' - mu(s) N Sign(s'),
    mu(s) = mu_k + (mu_s - mu_k) exp(-|s| / Dc)          (slip weakening over Dc).

Sign is set-valued at s' = 0: in the stick the friction force is whatever keeps the block
still, up to mu(s) N. nivpjax solves the inclusion directly (friction acts on the velocity
through the proximal map of mu N |v|, no extra states, no regularisation); the friction force
per unit mass comes back as the velocity row of `Solution.multipliers`.

Maths of the references.

1. Undriven, undamped, constant friction F = mu N. While slipping with sign sigma the block
   oscillates harmonically about s_c = -sigma F / k with omega = sqrt(k/m); the velocity
   vanishes again after less than half a period, each half-swing 2F/k shorter in amplitude.
   At v = 0 the block sticks for good if |k s| <= F, otherwise it swings back. The phases are
   in closed form (launched at v0 = 0.9 with mu = 0.1: five half-swings, stuck at
   t = 14.0265, s = 0.00554).
2. Driven (V = 0.1), slip-weakening mu_s = 0.6 -> mu_k = 0.3 over Dc = 1: the block sticks
   until the spring force k V t reaches mu_s N (t = 6), slips, sticks again when v = 0 with
   |k(Vt - s)| <= mu(s) N, and so on. Stick phases are exact (s frozen, the force grows
   linearly); slip phases are integrated with DOP853 at rtol 1e-12 up to the event v = 0.

The script solves both cases with Bathe's scheme and a PID controller at three tolerances
(one compiled function: tolerances, parameters and initial states are inputs), prints the
errors and the compile and run times, and plots the trajectories, friction forces and steps.

What to expect: case 2 (stick-slip transitions only) converges with the tolerance. In case 1
the error stalls near 1e-4: a reversal (v changing sign while slipping) that falls in the
first half of a step makes the same error in the full step and in the two half steps of the
Richardson estimate, so the controller does not see it and does not locate that reversal.

Run:  python examples/spring_slider.py      (writes examples/output/spring_slider.png; ~20 s)
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
from _references_mechanics import (  # noqa: E402
    output_path,
    slider_constant_friction,
    slider_constant_friction_state,
    slider_event_driven,
    timed,
)

import nivpjax as nj  # noqa: E402


jax.config.update("jax_enable_x64", True)

scene, _, _ = nj.scenes.spring_slider()
MU_A, V0_A, T_A = 0.1, 0.9, 16.0
CASE_A = nj.scenes.spring_slider(mu_static=MU_A, mu_kinetic=MU_A, velocity=V0_A)[1:]
DRIVEN = dict(mu_static=0.6, mu_kinetic=0.3, slip_scale=1.0, drive_velocity=0.1, velocity=0.0)
CASE_B = nj.scenes.spring_slider(**DRIVEN)[1:]
T_B = 40.0


@eqx.filter_jit
def solve(rtol, t1, x0, args):
    # One executable for both cases and every tolerance: all of these are traced inputs.
    controller = nj.PIDController(rtol=rtol, atol=1e-2 * rtol)
    return scene.solve(
        0.0, t1, x0, args, stepper=nj.Bathe(), controller=controller, max_steps=20000, throw=False
    )


def case_a(sol):
    s = sol.trimmed()
    ts, ys = np.asarray(s.ts), np.asarray(s.ys)
    phases, t_stick = slider_constant_friction(0.0, V0_A, 1.0, 1.0, MU_A, 1.0, T_A)
    s_ref, v_ref = slider_constant_friction_state(ts, phases, 1.0, 1.0, MU_A, 1.0)
    k = np.flatnonzero(np.abs(ys[:, 1]) > 1e-12)[-1] + 1  # first step ending in the stick
    return dict(
        ts=ts,
        ys=ys,
        mult=np.asarray(s.multipliers),
        hs=np.asarray(s.hs),
        err=np.max(np.maximum(np.abs(ys[:, 0] - s_ref), np.abs(ys[:, 1] - v_ref))),
        stick=(t_stick, ts[k - 1], ts[k]),
        s_err=abs(ys[-1, 0] - phases[-1][1]),
    )


def case_b(sol):
    s = sol.trimmed()
    ts, ys = np.asarray(s.ts), np.asarray(s.ys)
    p = {k: float(v) for k, v in CASE_B[1].items()}
    s_ref, v_ref, switches = slider_event_driven(p, 0.0, 0.0, T_B, ts)
    stuck = np.abs(ys[:, 1]) < 1e-12
    change = np.flatnonzero(stuck[1:] != stuck[:-1])
    # Distance from each exact switch to the step in which the numerical solution switches.
    miss = [max(ts[i] - t, t - ts[i + 1], 0.0) for i, (t, _) in zip(change, switches[1:])] or [
        np.inf
    ]
    return dict(
        ts=ts,
        ys=ys,
        mult=np.asarray(s.multipliers),
        hs=np.asarray(s.hs),
        err=np.max(np.maximum(np.abs(ys[:, 0] - s_ref), np.abs(ys[:, 1] - v_ref))),
        switches=switches,
        n_switch=(change.size, len(switches) - 1),
        miss=max(miss),
    )


def main():
    rtol = jnp.asarray(1e-6)
    sol_a, t_first = timed(solve, rtol, jnp.asarray(T_A), *CASE_A)
    sol_a, t_run = timed(solve, rtol, jnp.asarray(T_A), *CASE_A)
    print("spring slider, m = k = N = 1; Bathe + PID")
    print(f"compile {t_first - t_run:.2f} s, run {1e3 * t_run:.1f} ms (case 1, rtol 1e-6)")

    phases, t_stick = slider_constant_friction(0.0, V0_A, 1.0, 1.0, MU_A, 1.0, T_A)
    print(
        f"\n1. constant friction mu = {MU_A}, v0 = {V0_A}: exact stick at t = {t_stick:.6f}, "
        f"s = {phases[-1][1]:.8f} after {len(phases) - 1} half-swings"
    )
    print(
        f"{'rtol':>7} {'steps':>6} {'rej':>4} {'run ms':>7} {'traj err':>9} "
        f"{'stick step':>23} {'|s_stick err|':>14}"
    )
    for tol in (1e-4, 1e-6, 1e-8):
        s, elapsed = timed(solve, jnp.asarray(tol), jnp.asarray(T_A), *CASE_A)
        assert s.result == nj.RESULTS.successful
        a = case_a(s)
        bracket = f"[{a['stick'][1]:.4f}, {a['stick'][2]:.4f}]"
        print(
            f"{tol:7.0e} {int(s.n_accepted):6d} {int(s.n_rejected):4d} {1e3 * elapsed:7.1f} "
            f"{a['err']:9.2e} {bracket:>23} {a['s_err']:14.2e}"
        )

    p = {k: float(v) for k, v in CASE_B[1].items()}
    _, _, switches = slider_event_driven(p, 0.0, 0.0, T_B, np.array([0.0]))
    sticks = [f"{t:.3f}" for t, m in switches if m == 0][1:]
    print(
        f"\n2. driven V = {p['V']}, mu_s = {p['mu_s']} -> mu_k = {p['mu_k']} over Dc = "
        f"{p['Dc']}: breakaway at t = 6, re-sticks at t = {', '.join(sticks)}"
    )
    print(
        f"{'rtol':>7} {'steps':>6} {'rej':>4} {'run ms':>7} {'traj err':>9} "
        f"{'switches':>9} {'max switch miss':>16}"
    )
    for tol in (1e-4, 1e-6, 1e-8):
        s, elapsed = timed(solve, jnp.asarray(tol), jnp.asarray(T_B), *CASE_B)
        assert s.result == nj.RESULTS.successful
        b = case_b(s)
        print(
            f"{tol:7.0e} {int(s.n_accepted):6d} {int(s.n_rejected):4d} {1e3 * elapsed:7.1f} "
            f"{b['err']:9.2e} {b['n_switch'][0]:4d}/{b['n_switch'][1]:<4d} {b['miss']:16.1e}"
        )

    a = case_a(solve(rtol, jnp.asarray(T_A), *CASE_A))
    b = case_b(solve(rtol, jnp.asarray(T_B), *CASE_B))
    ta = np.linspace(0, T_A, 3000)
    sa, va = slider_constant_friction_state(ta, phases, 1.0, 1.0, MU_A, 1.0)
    tb = np.linspace(0, T_B, 4000)
    sb, vb, _ = slider_event_driven(p, 0.0, 0.0, T_B, tb)
    fig, axes = plt.subplots(4, 2, figsize=(11, 9), sharex="col")
    for col, (r, tt, ss, vv, title) in enumerate(
        [
            (a, ta, sa, va, f"1. free, mu = {MU_A}: slip, then stick"),
            (b, tb, sb, vb, "2. driven stick-slip, slip weakening"),
        ]
    ):
        ax = axes[:, col]
        ax[0].set_title(title)
        ax[0].plot(tt, ss, "k-", lw=1, label="exact")
        ax[0].plot(r["ts"], r["ys"][:, 0], "o", ms=2, label="nivpjax (rtol 1e-6)")
        ax[0].set_ylabel("position s")
        ax[0].legend()
        ax[1].plot(tt, vv, "k-", lw=1)
        ax[1].plot(r["ts"], r["ys"][:, 1], "o", ms=2)
        ax[1].set_ylabel("velocity v")
        ax[2].plot(r["ts"][1:], r["mult"][1:, 1], ".", ms=2, label="friction force")
        if col == 0:
            ax[2].axhline(MU_A, color="grey", ls=":", lw=1)
            ax[2].axhline(-MU_A, color="grey", ls=":", lw=1, label="+-mu N")
        else:
            mu = p["mu_k"] + (p["mu_s"] - p["mu_k"]) * np.exp(-np.abs(sb) / p["Dc"])
            ax[2].plot(tb, -mu, color="grey", ls=":", lw=1, label="-mu(s) N")
        ax[2].set_ylabel("friction / m")
        ax[2].legend()
        ax[3].semilogy(r["ts"][1:], r["hs"][1:], ".-", ms=2)
        ax[3].set_ylabel("accepted step h")
        ax[3].set_xlabel("t")
    fig.tight_layout()
    path = output_path("spring_slider.png")
    fig.savefig(path, dpi=120)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
