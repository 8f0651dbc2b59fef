r"""Issue 32's tables as the issue poses them: friction through its effect against the same
law written into $f$ as a smooth function, on four sliding problems with no event (the
speed stays far from zero, so the exact solution is a smooth ODE).

- disk: `nj.scenes.block_on_plane(push=...)`, $p' = v$, $v' = F(t) - r$,
  $r \in \mu g\,\partial|v|$, $F = 1.5(\cos 2t, \sin 2t)$, $\mu g = 1$, $v(0) = (0.5, 0.3)$,
  $T = 8$ (the issue's problem, with the positions: `Friction`, disk);
- slip weakening: $x'' = 0.2\sin t - \mu(x)\,\mathrm{sign}(x')$,
  $\mu = 0.4 + 0.3 e^{-|x|/0.5}$, $x(0) = 0$, $x'(0) = 8$, $T = 6$ (`Friction`, interval
  with a state-dependent bound);
- cone: the disk problem with contact and friction in one second-order cone
  (`block_on_plane(cone=True, push=...)`: multipliers that enter $f$);
- slider: `nj.scenes.spring_slider` in continuous slip, slip weakening 0.6 to 0.4 over
  $D_c = 0.5$, driven at $V = 1$ from $v(0) = 1.5$, $T = 10$ (least speed 0.39).

Default PID, atol = rtol / 100; errors: the largest over the accepted steps and the whole
state against DOP853 at rtol 1e-13 on the smooth field. Fixed steps (`ConstantStepSize`):
each problem over [0, 4], h = 0.04 .. 0.005.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.sliding_order

Writes benchmarks/results/sliding_order.md.
"""

import os
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import nivpjax as nj  # noqa: E402


jax.config.update("jax_enable_x64", True)
OUT = Path(__file__).resolve().parent / "results" / "sliding_order.md"
STEPPERS = {"Bathe": nj.Bathe, "Trapezoidal": nj.Trapezoidal, "BackwardEuler": nj.BackwardEuler}
RTOLS = (1e-3, 1e-5, 1e-7, 1e-8)


def _mu(x):
    return 0.4 + 0.3 * jnp.exp(-jnp.abs(x[0]) / 0.5)


def _norm(v):
    return jnp.sqrt(jnp.sum(v**2))


_G = 9.81
_DISK = nj.scenes.block_on_plane(mu=1 / _G, velocity=(0.5, 0.3), push=(1.5, 2.0))
_CONE = nj.scenes.block_on_plane(mu=1 / _G, velocity=(0.5, 0.3), push=(1.5, 2.0), cone=True)
_SLIDER = nj.scenes.spring_slider(
    mu_static=0.6, mu_kinetic=0.4, slip_scale=0.5, drive_velocity=1.0, velocity=1.5
)


def _push(t, a):
    return a["A"] * jnp.stack([jnp.cos(a["omega"] * t), jnp.sin(a["omega"] * t)])


def _pushed_field(cone):
    # p' = v, v_t' = F(t) - mu g v_t/|v_t| (and p_n' = v_n, v_n' = 0 on the cone).
    def field(t, y, a):
        k = 3 if cone else 2
        v = y[k : 2 * k]
        vt = v[:2]
        accel = _push(t, a) - a["mu"] * a["g"] * vt / _norm(vt)
        return jnp.concatenate([v, accel, jnp.zeros(k - 2, y.dtype)])

    return field


def _slider_field(t, y, a):
    mu = a["mu_k"] + (a["mu_s"] - a["mu_k"]) * jnp.exp(-jnp.abs(y[0]) / a["Dc"])
    force = a["k"] * (a["V"] * t - y[0]) - a["c"] * y[1] - mu * a["N"] * jnp.sign(y[1])
    return jnp.stack([y[1], force / a["m"]])


PROBLEMS = {  # name: ((effect scene, x0, args), smooth field, T)
    "disk": (_DISK, _pushed_field(False), 8.0),
    "weakening": (
        (
            nj.Scene(
                lambda t, x, a, m: jnp.stack([x[1], 0.2 * jnp.sin(t)]),
                2,
                (nj.Friction([1], lambda t, x, a: _mu(x)),),
            ),
            jnp.asarray([0.0, 8.0]),
            {},
        ),
        lambda t, y, a: jnp.stack([y[1], 0.2 * jnp.sin(t) - _mu(y) * jnp.sign(y[1])]),
        6.0,
    ),
    "cone": (_CONE, _pushed_field(True), 8.0),
    "slider": (_SLIDER, _slider_field, 10.0),
}


def exact(name, ts):
    """The smooth ODE by DOP853 at rtol 1e-13 (numpy, no nivpjax)."""
    (_, x0, args), field, _ = PROBLEMS[name]

    def rhs(t, y):
        return np.asarray(field(t, jnp.asarray(y), args))

    y0 = np.asarray(x0)
    sol = solve_ivp(rhs, (0, ts[-1]), y0, t_eval=ts, rtol=1e-13, atol=1e-14, method="DOP853")
    return sol.y.T


def _error(name, sol):
    k = int(sol.n_accepted)
    ts, xs = np.asarray(sol.ts[: k + 1]), np.asarray(sol.ys[: k + 1])
    n = len(PROBLEMS[name][0][1])
    return float(np.max(np.abs(xs[:, :n] - exact(name, ts)))), k


def solve_either(scene, field, smooth, t1, x0, args, **kw):
    """From 0 to `t1` through the effect (`scene`) or with the law in f (`field`, where
    `smooth`)."""
    if smooth:
        return nj.solve(field, 0.0, t1, x0, args, **kw)
    return scene.solve(0.0, t1, x0, args, **kw)


def _solve(name, stepper, smooth, t1, **kw):
    (scene, x0, args), field, _ = PROBLEMS[name]
    return solve_either(scene, field, smooth, t1, x0, args, stepper=STEPPERS[stepper](), **kw)


def adaptive(name, stepper, smooth):
    """`run(rtol) -> (error, accepted steps)`, one compile per configuration."""
    T = PROBLEMS[name][2]

    @jax.jit
    def run(rtol):
        controller = nj.PIDController(rtol=rtol, atol=rtol / 100)
        return _solve(name, stepper, smooth, T, controller=controller, max_steps=200_000)

    def measure(rtol):
        sol = run(jnp.asarray(rtol))
        assert sol.result == nj.RESULTS.successful, (name, stepper, smooth, rtol)
        return _error(name, sol)

    return measure


def fixed(name, stepper, smooth, hs=(0.04, 0.02, 0.01, 0.005)):
    """Errors over [0, 4] at fixed steps, and the observed orders."""

    @jax.jit
    def run(h):
        controller = nj.ConstantStepSize()
        return _solve(name, stepper, smooth, 4.0, controller=controller, h0=h, max_steps=1024)

    errors = [_error(name, run(jnp.asarray(h)))[0] for h in hs]
    return errors, np.log2(np.array(errors[:-1]) / np.array(errors[1:]))


def _cell(err, k):
    return f"{err:.1e} ({k})"


def _label(stepper, smooth):
    return f"{stepper}, {'smooth field' if smooth else 'through the effect'}"


def main():
    lines = ["# Issue 32's tables on the current code", ""]
    for name in PROBLEMS:
        lines += [f"## {name} (error, accepted steps)", ""]
        lines += ["| stepper | " + " | ".join(f"rtol {r:.0e}" for r in RTOLS) + " |"]
        lines += ["|---|" + "---|" * len(RTOLS)]
        for stepper in STEPPERS:
            for smooth in (False, True):
                if smooth and stepper == "BackwardEuler":
                    continue
                run = adaptive(name, stepper, smooth)
                # Backward Euler (first order) at 1e-8 would need about 10^6 steps.
                rtols = RTOLS[:-1] if stepper == "BackwardEuler" else RTOLS
                cells = [_cell(*run(r)) for r in rtols] + ["-"] * (len(RTOLS) - len(rtols))
                lines.append(f"| {_label(stepper, smooth)} | " + " | ".join(cells) + " |")
                print(lines[-1], flush=True)
        lines.append("")
    lines += ["## Fixed steps over [0, 4], h = 0.04, 0.02, 0.01, 0.005 (errors; orders)", ""]
    for name in PROBLEMS:
        for stepper in ("Bathe", "Trapezoidal"):
            for smooth in (False, True):
                errors, orders = fixed(name, stepper, smooth)
                lines.append(
                    f"- {name}, {_label(stepper, smooth)}: "
                    + ", ".join(f"{e:.1e}" for e in errors)
                    + " (orders "
                    + ", ".join(f"{o:.2f}" for o in orders)
                    + ")"
                )
                print(lines[-1], flush=True)
    OUT.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
