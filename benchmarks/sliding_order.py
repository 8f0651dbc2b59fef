r"""Issue 32's tables as the issue poses them: friction through `nj.Friction` against the same
law written into $f$ as a smooth function, on two sliding problems with no event (the
velocity stays far from zero, so the exact solution is a smooth ODE).

- disk: $v' = F(t) - r$, $r \in c\,\partial|v|$, $F = 1.5(\cos 2t, \sin 2t)$, $c = 1$,
  $v(0) = (0.5, 0.3)$, $T = 8$;
- slip weakening: $x'' = 0.2\sin t - \mu(x)\,\mathrm{sign}(x')$,
  $\mu = 0.4 + 0.3 e^{-|x|/0.5}$, $x(0) = 0$, $x'(0) = 8$, $T = 6$.

Default PID, atol = rtol / 100; errors: the largest over the accepted steps against DOP853
at rtol 1e-13. Fixed steps (`ConstantStepSize`): the disk over [0, 4], h = 0.04 .. 0.005.

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
RTOLS = (1e-3, 1e-5, 1e-7)


def _push(t):
    return jnp.stack([1.5 * jnp.cos(2 * t), 1.5 * jnp.sin(2 * t)])


def _mu(x):
    return 0.4 + 0.3 * jnp.exp(-jnp.abs(x[0]) / 0.5)


def _norm(v):
    return jnp.sqrt(jnp.sum(v**2))


PROBLEMS = {  # name: (effect scene, smooth field, x0, T)
    "disk": (
        nj.Scene(lambda t, x, a, m: _push(t), 2, (nj.Friction([0, 1], 1.0, isotropic=True),)),
        lambda t, y, a: _push(t) - y / _norm(y),
        (0.5, 0.3),
        8.0,
    ),
    "weakening": (
        nj.Scene(
            lambda t, x, a, m: jnp.stack([x[1], 0.2 * jnp.sin(t)]),
            2,
            (nj.Friction([1], lambda t, x, a: _mu(x)),),
        ),
        lambda t, y, a: jnp.stack([y[1], 0.2 * jnp.sin(t) - _mu(y) * jnp.sign(y[1])]),
        (0.0, 8.0),
        6.0,
    ),
}


def exact(name, ts):
    """The smooth ODE by DOP853 at rtol 1e-13 (numpy, no nivpjax)."""
    _, field, x0, _ = PROBLEMS[name]

    def rhs(t, y):
        return np.asarray(field(t, jnp.asarray(y), None))

    sol = solve_ivp(rhs, (0, ts[-1]), x0, t_eval=ts, rtol=1e-13, atol=1e-14, method="DOP853")
    return sol.y.T


def _error(name, sol):
    k = int(sol.n_accepted)
    ts, xs = np.asarray(sol.ts[: k + 1]), np.asarray(sol.ys[: k + 1])
    return float(np.max(np.abs(xs[:, :2] - exact(name, ts)))), k


def _solve(name, stepper, smooth, t1, **kw):
    # The problem through `Friction` (its scene) or with the law in f (`smooth`).
    scene, field, x0, _ = PROBLEMS[name]
    kw["stepper"] = STEPPERS[stepper]()
    if smooth:
        return nj.solve(field, 0.0, t1, jnp.asarray(x0), **kw)
    return scene.solve(0.0, t1, jnp.asarray(x0), **kw)


def adaptive(name, stepper, smooth):
    """`run(rtol) -> (error, accepted steps)`, one compile per configuration."""
    T = PROBLEMS[name][3]

    @jax.jit
    def run(rtol):
        controller = nj.PIDController(rtol=rtol, atol=rtol / 100)
        return _solve(name, stepper, smooth, T, controller=controller, max_steps=100_000)

    def measure(rtol):
        sol = run(jnp.asarray(rtol))
        assert sol.result == nj.RESULTS.successful, (name, stepper, smooth, rtol)
        return _error(name, sol)

    return measure


def fixed(stepper, smooth, hs=(0.04, 0.02, 0.01, 0.005)):
    """Errors on the disk over [0, 4] at fixed steps, and the observed orders."""

    @jax.jit
    def run(h):
        controller = nj.ConstantStepSize()
        return _solve("disk", stepper, smooth, 4.0, controller=controller, h0=h, max_steps=1024)

    errors = [_error("disk", run(jnp.asarray(h)))[0] for h in hs]
    return errors, np.log2(np.array(errors[:-1]) / np.array(errors[1:]))


def _cell(err, k):
    return f"{err:.1e} ({k})"


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
                cells = [_cell(*run(r)) for r in RTOLS]
                label = f"{stepper}, {'smooth field' if smooth else '`Friction`'}"
                lines.append(f"| {label} | " + " | ".join(cells) + " |")
                print(lines[-1], flush=True)
        lines.append("")
    lines += ["## disk at fixed steps, h = 0.04, 0.02, 0.01, 0.005 (errors; orders)", ""]
    for stepper in ("Bathe", "Trapezoidal"):
        for smooth in (False, True):
            errors, orders = fixed(stepper, smooth)
            label = f"{stepper}, {'smooth field' if smooth else '`Friction`'}"
            lines.append(
                f"- {label}: "
                + ", ".join(f"{e:.1e}" for e in errors)
                + " (orders "
                + ", ".join(f"{o:.2f}" for o in orders)
                + ")"
            )
            print(lines[-1], flush=True)
    OUT.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
