"""Issue 33's targets measured on the current code: a bead against a circular wall and a ball
in a bowl, exactly as the issue poses them.

- bead: no gravity, q(0) = (1, 0), v(0) = (0, 1), T = 4 (exact: uniform on the circle);
- bowl: g = 9.81, q(0) = (0, -1), v(0) = (1, 0), T = 4 (reference: `bowl_state`, the
  pendulum by DOP853 at rtol 1e-13);
- thrown: g = 9.81, q(0) = (0, -1), v(0) = (6, 0), T = 2: released where N = 0, a
  parabola, a plastic landing (reference: `bowl_pieces`, event-driven, converged: the
  pendulum to N = 0 at rtol 1e-13, the landing by root finding at xtol 1e-15).

`nj.scenes.ball_in_bowl` (R = 1, e = 0). Adaptive: the default PID controller, atol = rtol/100,
rtol 1e-3 .. 1e-8, every implicit stepper; per run the result, the accepted and rejected
steps, the largest state error over the accepted steps, the deepest gap over atol + rtol R,
the smallest normal reaction N = -r . q/|q| at the steps (its sign), and on the thrown ball
the release (the last step on the wall before the flight) and the landing (the first step
back on it) against the reference's times. Fixed steps: `ConstantStepSize`, h = 0.04 ..
0.005 (bead) and 0.02 .. 0.005 (bowl), the largest state error over the steps, and the
observed orders.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.bowl_audit [--quick] [--thrown]

Writes benchmarks/results/bowl_audit.json (the table in bowl_audit.md quotes it).
"""

import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import nivpjax as nj


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
from _references_mechanics import bowl_pieces, bowl_state  # noqa: E402


jax.config.update("jax_enable_x64", True)
G = 9.81
OUT = Path(__file__).resolve().parent / "results" / "bowl_audit.json"
SCENE, _, ARGS = nj.scenes.ball_in_bowl()
STEPPERS = {
    "BackwardEuler": nj.BackwardEuler,
    "Trapezoidal": nj.Trapezoidal,
    "Bathe": nj.Bathe,
    "EmbeddedBETR": nj.EmbeddedBETR,
}
CASES = {  # x0, g, T
    "bead": ((1.0, 0.0, 0.0, 1.0), 0.0, 4.0),
    "bowl": ((0.0, -1.0, 1.0, 0.0), G, 4.0),
    "thrown": ((0.0, -1.0, 6.0, 0.0), G, 2.0),
}
RTOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)
MAX_STEPS = 400_000


def exact(case, ts):
    x0, g, _ = CASES[case]
    if case == "bead":
        return np.stack([np.cos(ts), np.sin(ts), -np.sin(ts), np.cos(ts)], -1)
    return bowl_state(ts, x0[2], g)


def _args(g):
    return dict(ARGS, g=jnp.asarray(g))


def _solve(stepper, x0, g, t1, **kw):
    return SCENE.solve(0.0, t1, x0, _args(g), stepper=STEPPERS[stepper](), **kw)


def adaptive_runner(stepper):
    @jax.jit
    def run(x0, g, t1, rtol):
        controller = nj.PIDController(rtol=rtol, atol=rtol / 100)
        return _solve(stepper, x0, g, t1, controller=controller, max_steps=MAX_STEPS)

    return run


def fixed_runner(stepper):
    @jax.jit
    def run(x0, g, t1, h):
        controller = nj.ConstantStepSize()
        return _solve(stepper, x0, g, t1, controller=controller, h0=h, max_steps=1024)

    return run


def trajectory(sol):
    k = int(sol.n_accepted)
    return (
        np.asarray(sol.ts[: k + 1]),
        np.asarray(sol.ys[: k + 1]),
        np.asarray(sol.multipliers[: k + 1]),
    )


def events(ts, gap, normal, tol, rtol):
    """The release and the landing from the steps: the release the end of the last step
    whose normal reaction exceeds `rtol` times its largest before the flight (the first
    step open by more than 1e-2, mid-flight; a reaction below that is zero to the
    tolerance), the landing the first step after it whose gap is within `tol` (atol +
    rtol R) of the wall."""
    flight = int(np.argmax(gap > 1e-2))
    pressed = np.nonzero(normal[:flight] > rtol * np.max(normal))[0]
    back = np.nonzero(gap[flight:] <= tol)[0]
    release = float(ts[1:][pressed[-1]]) if pressed.size else np.nan
    landing = float(ts[flight + back[0]]) if back.size else np.nan
    return release, landing


def measure(case, stepper, runner, rtol):
    x0, g, t1 = CASES[case]
    args = (jnp.asarray(x0), jnp.asarray(g), jnp.asarray(t1), jnp.asarray(rtol))
    start = time.perf_counter()
    sol = jax.block_until_ready(runner(*args))
    seconds = time.perf_counter() - start
    ts, ys, r = trajectory(sol)
    q = ys[:, :2]
    gap = 1.0 - np.linalg.norm(q, axis=1)
    normal = -np.sum(r[1:, 2:] * q[1:], axis=1) / np.linalg.norm(q[1:], axis=1)
    row = dict(
        case=case,
        stepper=stepper,
        rtol=rtol,
        result=str(sol.result),
        successful=bool(sol.result == nj.RESULTS.successful),
        t_final=float(sol.t_final),
        accepted=int(sol.n_accepted),
        rejected=int(sol.n_rejected),
        error=float(np.max(np.abs(ys - exact(case, ts)))),
        position_error=float(np.max(np.abs(q - exact(case, ts)[:, :2]))),
        deepest=float(max(0.0, -np.min(gap))),
        gap_ratio=float(max(0.0, -np.min(gap)) / (rtol / 100 + rtol * 1.0)),
        min_normal=float(np.min(normal)),
        max_normal=float(np.max(normal)),
        seconds=seconds,
    )
    if case == "thrown":
        pieces = bowl_pieces(x0[2], g, t1)
        release, landing = events(ts, gap, normal, rtol / 100 + rtol, rtol)
        row.update(
            release=release,
            landing=landing,
            release_ref=float(pieces[0][1]),
            landing_ref=float(pieces[1][1]),
            release_error=abs(release - pieces[0][1]),
            landing_error=abs(landing - pieces[1][1]),
        )
    return row


def fixed(case, stepper, runner, hs):
    x0, g, t1 = CASES[case]
    errors = []
    for h in hs:
        sol = runner(jnp.asarray(x0), jnp.asarray(g), jnp.asarray(t1), jnp.asarray(h))
        assert sol.result == nj.RESULTS.successful, (case, stepper, h, sol.result)
        ts, ys, _ = trajectory(sol)
        assert abs(ts[-1] - t1) < 1e-12
        errors.append(float(np.max(np.abs(ys - exact(case, ts)))))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    return dict(case=case, stepper=stepper, hs=list(hs), errors=errors, orders=orders.tolist())


def main():
    quick = "--quick" in sys.argv
    rtols = RTOLS[::2] if quick else RTOLS
    thrown_only = "--thrown" in sys.argv  # rerun the thrown ball's rows only
    out = json.loads(OUT.read_text()) if thrown_only else dict(adaptive=[], fixed=[])
    if thrown_only:
        out["adaptive"] = [row for row in out["adaptive"] if row["case"] != "thrown"]
    for stepper in STEPPERS:
        if stepper != "EmbeddedBETR" and not thrown_only:
            runner = fixed_runner(stepper)
            for case, hs in (("bead", (0.04, 0.02, 0.01, 0.005)), ("bowl", (0.02, 0.01, 0.005))):
                out["fixed"].append(fixed(case, stepper, runner, hs))
                print(out["fixed"][-1], flush=True)
        runner = adaptive_runner(stepper)
        for case in ("thrown",) if thrown_only else CASES:
            for rtol in rtols:
                out["adaptive"].append(measure(case, stepper, runner, rtol))
                row = out["adaptive"][-1]
                print({k: row[k] for k in row if k not in ("case", "stepper")}, case, stepper)
                sys.stdout.flush()
    OUT.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
