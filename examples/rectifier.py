"""Diode rectifiers: a half-wave rectifier and a four-diode (Graetz) bridge with an RC load.

The models (`nivpjax.scenes.half_wave_rectifier`, `nivpjax.scenes.diode_bridge`): a source
V sin(wt) (V = 1 V, 50 Hz) feeds a load capacitor C = 100 uF in parallel with R_L = 1 kOhm
through ideal diodes with series resistance R_s = 1 Ohm. With the load voltage v,

    C v' = i - v / R_L,     0 <= i  _|_  (src - v - R_s i) <= 0,

a linear complementarity condition per diode (pair): either i = 0 and the diode blocks
(src <= v), or it conducts and src - v = R_s i. Equivalently i = max(0, (src - v)/R_s).
The half-wave rectifier has one diode (src = V sin wt); the bridge has two pairs, D1-D2
conducting on the positive half-wave (src = V sin wt) and D3-D4 on the negative one
(src = -V sin wt), so the load sees |V sin wt|. nivpjax carries the currents as multipliers
i >= 0 solved with the state at each implicit stage, without event detection.

Reference. Each regime is a linear ODE with a closed-form solution: off, v decays as
exp(-t/(R_L C)); on, v' = -a v + b sin wt with a = 1/(R_s C) + 1/(R_L C), b = +-V/(R_s C),
solved by a sinusoid plus a decaying exponential. The switches are the roots of src(t) - v(t)
(conduction starts when the source overtakes v, ends when the current falls back to 0),
located by Brent's method to machine precision. The script reports the load voltage error on
the accepted steps, the error of the switching times read from the computed solution (roots
of src - v with v interpolated by cubic Hermite polynomials between accepted steps), the
complementarity residual, the wall time (compilation and run separately), and plots the
waveforms, the diode currents and the step sizes.

Pitfall shown at the end: with loose tolerances an adaptive step that grows during the long
blocking phase can jump over a whole conduction pulse (both step ends and all stage points
are outside it, so nothing signals it). Bound the step (PIDController(h_max=...)) to a
fraction of the source period when the forcing is time-dependent.

Run:  python examples/rectifier.py      (writes examples/output/rectifier.png; about 35 s)
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
    RectifierReference,
    output_path,
    rectifier_switch_times,
    run_timed,
    timed_solve,
)

import nivpjax as nj  # noqa: E402


jax.config.update("jax_enable_x64", True)

SCENES = {
    "half-wave": (nj.scenes.half_wave_rectifier(), False),
    "bridge": (nj.scenes.diode_bridge(), True),
}
PERIODS = 3


def make_solve(scene, h_max=None):
    def solve(t1, rtol, x0, args):
        controller = nj.PIDController(rtol=rtol, atol=1e-3 * rtol, h_max=h_max)
        return scene.solve(0.0, t1, x0, args, controller=controller, max_steps=8192, throw=False)

    return solve


def analyse(scene, sol, p, reference):
    sol = sol.trimmed()
    ts = np.asarray(sol.ts)
    x, m = scene.split(sol.ys)
    v, i = np.asarray(x[:, 0]), np.asarray(m["i"])
    intervals = reference.conduction()
    expected = np.sort(np.concatenate([intervals[1:, 0], intervals[:, 1]]))
    expected = expected[expected < ts[-1] - 1e-9]
    got = rectifier_switch_times(ts[1:], v[1:], i[1:], p["R_L"], p["C"], reference.src)
    switch_error = np.max(np.abs(got - expected)) if got.shape == expected.shape else np.inf
    e = p["V"] * np.sin(p["omega"] * ts[1:])
    signs = np.array([1.0, -1.0])[: i.shape[1]]
    complementarity = np.max(
        np.abs(i[1:] - np.maximum(0.0, (signs * e[:, None] - v[1:, None]) / p["R_s"]))
    )
    return dict(
        ts=ts,
        v=v,
        i=i,
        hs=np.asarray(sol.hs),
        v_error=np.max(np.abs(v - reference.v(ts))),
        switch_error=switch_error,
        n_switches=(got.size, expected.size),
        complementarity=complementarity,
        steps=(int(sol.n_accepted), int(sol.n_rejected)),
    )


def main():
    results, executables = {}, {}
    print(
        f"{'circuit':>9} {'rtol':>6} {'steps':>6} {'rej':>4} {'compile s':>9} {'run ms':>7} "
        f"{'max|v err| V':>12} {'switch err s':>12} {'complementarity':>15}"
    )
    for name, ((scene, x0, args), full) in SCENES.items():
        p = {k: float(v) for k, v in args.items()}
        t1 = PERIODS * 2 * np.pi / p["omega"]
        reference = RectifierReference(p["V"], p["omega"], p["R_s"], p["R_L"], p["C"], t1, full)
        compiled, sol, t_compile, t_run = timed_solve(
            make_solve(scene), jnp.asarray(t1), jnp.asarray(1e-6), x0, args
        )
        runs = {1e-6: (sol, t_run)}
        runs[1e-8] = run_timed(compiled, jnp.asarray(t1), jnp.asarray(1e-8), x0, args)
        executables[name] = compiled
        for tol, (s, elapsed) in runs.items():
            assert s.result == nj.RESULTS.successful
            q = analyse(scene, s, p, reference)
            print(
                f"{name:>9} {tol:6.0e} {q['steps'][0]:6d} {q['steps'][1]:4d} "
                f"{f'{t_compile:.2f}' if tol == 1e-6 else '-':>9} {1e3 * elapsed:7.1f} "
                f"{q['v_error']:12.2e} {q['switch_error']:12.2e} {q['complementarity']:15.1e}"
            )
        intervals = reference.conduction() * 1e3
        print(
            f"{'':>9} conduction intervals (ms): "
            + ", ".join(f"[{a:.4f}, {b:.4f}]" for a, b in intervals)
        )
        results[name] = (analyse(scene, sol, p, reference), reference, p, t1)

    # Pitfall: loose tolerances step over conduction pulses; h_max fixes it.
    (scene, x0, args), _ = SCENES["half-wave"]
    _, reference, p, t1 = results["half-wave"]
    t1_long = 5 * 2 * np.pi / p["omega"]
    reference = RectifierReference(p["V"], p["omega"], p["R_s"], p["R_L"], p["C"], t1_long, False)
    print("half-wave, 5 periods, rtol 1e-3 / atol 1e-6 (the default tolerances):")
    for h_max in (None, 1e-3):
        solve = executables["half-wave"] if h_max is None else jax.jit(make_solve(scene, h_max))
        s = solve(jnp.asarray(t1_long), jnp.asarray(1e-3), x0, args)
        q = analyse(scene, s, p, reference)
        label = "no h_max" if h_max is None else f"h_max = {h_max * 1e3:g} ms (T/20)"
        print(
            f"  {label:>22}: {q['steps'][0]:4d} steps, max|v err| = {q['v_error']:.2e} V, "
            f"{q['n_switches'][0]} of {q['n_switches'][1]} switches seen"
        )

    fig, axes = plt.subplots(3, 2, figsize=(11, 8), sharex=True)
    for col, (name, (q, reference, p, t1)) in enumerate(results.items()):
        tt = np.linspace(0, t1, 3000)
        ax = axes[0, col]
        ax.plot(1e3 * tt, p["V"] * np.sin(p["omega"] * tt), color="0.7", lw=1, label="V sin wt")
        if reference.full:
            ax.plot(1e3 * tt, reference.src(tt), color="0.7", ls="--", lw=1, label="|V sin wt|")
        ax.plot(1e3 * tt, reference.v(tt), "k-", lw=1, label="v, exact")
        ax.plot(1e3 * q["ts"], q["v"], "o", ms=2, label="v, nivpjax (rtol 1e-6)")
        for a, b in reference.conduction():
            ax.axvspan(1e3 * a, 1e3 * b, color="C1", alpha=0.15, lw=0)
        ax.set_title(f"{name} rectifier (shaded: conducting)")
        ax.set_ylabel("voltage (V)")
        ax.legend(fontsize=8, loc="lower left")
        ax = axes[1, col]
        ax.plot(1e3 * tt, reference.current(tt), "k-", lw=1, label="exact")
        for j in range(q["i"].shape[1]):
            label = "i" if q["i"].shape[1] == 1 else ("i (D1, D2)", "i (D3, D4)")[j]
            ax.plot(1e3 * q["ts"][1:], q["i"][1:, j], "o", ms=2, label=label)
        ax.set_ylabel("diode current (A)")
        ax.legend(fontsize=8)
        ax = axes[2, col]
        ax.semilogy(1e3 * q["ts"][1:], q["hs"][1:], ".-", ms=3)
        ax.set_ylabel("accepted step h (s)")
        ax.set_xlabel("t (ms)")
    fig.tight_layout()
    path = output_path("rectifier.png")
    fig.savefig(path, dpi=120)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
