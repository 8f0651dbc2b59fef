r"""The stick-slip family against its smooth law: where its error is made, and the
constant the campaign's rule owes it.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.stick_slip_smooth

Inside a slip phase of the spring-slider (`benchmarks.families.STICK_SLIP`) the friction
force is $\sigma\mu(s)N$ with the slip direction $\sigma$ fixed: the flow is the smooth
ODE with that law written into $f$,

$$ m s'' = k(Vt - s) - c s' - \sigma\,\mu(s) N, $$

the cheap reference for every nonsmooth effect: whatever a scheme makes on it at a
tolerance, it makes with the friction law too, and nothing the nonsmooth solve adds may
be larger. Per grid point, stepper and rtol this runs each slip phase twice from the
exact state at its start, with the friction scene and with the smooth law, to the end
of the phase (default controller, semismooth Newton), and the whole horizon with the
friction scene:

- `smooth`, `friction`: the largest error over the phase (against the event-driven
  reference), divided by `rtol^q` (q = 2/3 for order 2, 1/2 for order 1);
- `sum`: the smooth constants of all slip phases added (a stick carries the position
  error of the slip before it unchanged, so phase errors add);
- `full`: the whole run's constant, as the campaign measures it.

`full` = `sum` says that no error is made at the transitions (stick to slip, slip to
stick): the run's error is the smooth flow's. Writes
`benchmarks/results/stick_slip_smooth.md`.
"""

import argparse
import os
from pathlib import Path

import numpy as np


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import nivpjax as nj  # noqa: E402

from . import reliability as campaign  # noqa: E402
from .families import STICK_SLIP, _floats, slider_event_driven  # noqa: E402


jax.config.update("jax_enable_x64", True)

RESULTS = Path(__file__).resolve().parent / "results"
T1 = STICK_SLIP.t1
RTOLS = (1e-4, 1e-5, 1e-6, 1e-7)
FIRST_ORDER_RTOLS = (1e-3, 1e-4, 1e-5)


def _smooth_dynamics(sigma):
    def dynamics(t, x, a, m):
        s, v = x
        mu = a["mu_k"] + (a["mu_s"] - a["mu_k"]) * jnp.exp(-jnp.abs(s) / a["Dc"])
        force = a["k"] * (a["V"] * t - s) - a["c"] * v - sigma * mu * a["N"]
        return jnp.stack([v, force / a["m"]])

    return dynamics


def slip_phases(params):
    """`[(t_start, t_end, sigma)]`: the exact slip phases of a grid point over the horizon."""
    _, _, args = STICK_SLIP.make(params)
    _, _, switches = slider_event_driven(_floats(args), 0.0, 0.0, T1, np.zeros(1))
    ends = [t for t, _ in switches[1:]] + [T1]
    return [(t, end, mode) for (t, mode), end in zip(switches, ends) if mode != 0]


def _reference(args, ts):
    s, v, _ = slider_event_driven(_floats(args), 0.0, 0.0, T1, ts)
    return np.stack([s, v], axis=-1)


def _error(args, sol):
    k = int(sol.n_accepted)
    ts, xs = np.asarray(sol.ts[: k + 1]), np.asarray(sol.ys[: k + 1])[:, :2]
    assert int(sol.result._value) == 0, sol.result
    return float(np.max(np.abs(xs - _reference(args, ts))))


def make_runs(stepper):
    """`(runs, full)`, jitted solves of one stepper: `runs[key](t0, t1, y0, args, rtol)`
    over one slip phase, with the smooth law of slip direction `key` (+1 or -1) or with
    the friction scene (`key = "friction"`), and `full(args, rtol)` over the horizon
    with the friction scene."""
    scene, x0, _ = STICK_SLIP.make(STICK_SLIP.grid[0])
    step = campaign.STEPPERS[stepper][0](solver=nj.SemismoothNewton())
    smooth = {s: nj.Scene(_smooth_dynamics(s), 2, ()) for s in (-1, 1)}

    def solve(sc, t0, t1, y0, args, rtol):
        ctrl = campaign.controller("default", rtol, None)
        return sc.solve(
            t0, t1, y0, args, stepper=step, controller=ctrl, max_steps=campaign.MAX_STEPS,
            throw=False,
        )  # fmt: skip

    runs = {name: jax.jit(lambda *a, sc=sc: solve(sc, *a)) for name, sc in smooth.items()}
    runs["friction"] = jax.jit(lambda *a: solve(scene, *a))
    full = jax.jit(lambda args, rtol: solve(scene, 0.0, T1, x0, args, rtol))
    return runs, full


def constants(params, stepper, rtol, runs=None):
    """`dict`: per slip phase the smooth law's and the friction scene's error over it,
    both from the exact state at its start, their sums, and the whole run's error, all
    as constants `error / rtol^q` (see the module)."""
    runs, full = runs or make_runs(stepper)
    _, _, args = STICK_SLIP.make(params)
    q = STICK_SLIP.q(campaign.STEPPERS[stepper][1])
    smooth, friction = [], []
    for t0, t1, sigma in slip_phases(params):
        y0 = jnp.asarray(_reference(args, np.array([t0]))[0])
        smooth.append(_error(args, runs[sigma](t0, t1, y0, args, rtol)) / rtol**q)
        friction.append(_error(args, runs["friction"](t0, t1, y0, args, rtol)) / rtol**q)
    return dict(
        smooth=smooth,
        friction=friction,
        sum=sum(smooth),
        full=_error(args, full(args, rtol)) / rtol**q,
    )


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m benchmarks.stick_slip_smooth")
    parser.add_argument("--steppers", nargs="+", default=list(campaign.STEPPERS))
    parser.add_argument(
        "--rtols", nargs="+", type=float, help="default: 1e-4 to 1e-7, first order 1e-3 to 1e-5"
    )
    parser.add_argument("--out", default=str(RESULTS / "stick_slip_smooth.md"))
    a = parser.parse_args(argv)
    lines = [
        "Stick-slip (`benchmarks.families.STICK_SLIP`) against its smooth law, per slip "
        "phase from the exact state at its start (`python -m benchmarks.stick_slip_smooth`; "
        "constants error / rtol^q, semismooth Newton, default controller).",
        "",
        "| point | stepper | rtol | smooth per phase | friction per phase | smooth sum "
        "| full run | bound C |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for stepper in a.steppers:
        runs = make_runs(stepper)
        order = campaign.STEPPERS[stepper][1]
        C = STICK_SLIP.constant(order)
        rtols = a.rtols or (FIRST_ORDER_RTOLS if order == 1 else RTOLS)
        for g, params in enumerate(STICK_SLIP.grid):
            for rtol in rtols:
                c = constants(params, stepper, rtol, runs)
                row = (
                    f"| {g} | {stepper} | {rtol:.0e} | "
                    + ", ".join(f"{x:.2f}" for x in c["smooth"])
                    + " | "
                    + ", ".join(f"{x:.2f}" for x in c["friction"])
                    + f" | {c['sum']:.2f} | {c['full']:.2f} | {C:g} |"
                )
                print(row, flush=True)
                lines.append(row)
    Path(a.out).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
