r"""The continuous-slip slider family (`benchmarks.families.SLIDER_SLIP`) against its smooth
law: the constant the campaign's rule owes it.

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.slider_slip_smooth

The slider never stops on the family's grid, so its motion is the smooth ODE with the
friction law written into $f$ (`benchmarks.sliding_order._slider_field`). Per grid point,
stepper and rtol of the campaign (default controller, semismooth Newton), the whole
horizon is run twice, through `nj.Friction` (the family's scene) and with the smooth law,
and each error (against the family's event-driven reference) is divided by `rtol^q`
(q = 2/3 for order 2, 1/2 for order 1). Equal columns say that the friction adds no
error of its own; the smooth column's worst value per order is the constant the scheme
needs on this ODE. Writes `benchmarks/results/slider_slip_smooth.md`.
"""

import os
from pathlib import Path

import numpy as np


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

import nivpjax as nj  # noqa: E402

from . import reliability as campaign  # noqa: E402
from .families import FAMILIES  # noqa: E402
from .sliding_order import _slider_field, solve_either  # noqa: E402


OUT = Path(__file__).resolve().parent / "results" / "slider_slip_smooth.md"
FAMILY = FAMILIES["slider_slip"]


def _runs(scene, cls):
    def solve(smooth):
        def run(x0, args, rtol):
            kw = dict(
                stepper=cls(),
                controller=nj.PIDController(rtol=rtol, atol=rtol / 100),
                max_steps=campaign.MAX_STEPS,
                throw=False,
            )
            return solve_either(scene, _slider_field, smooth, FAMILY.t1, x0, args, **kw)

        return jax.jit(run)

    return solve(True), solve(False)


def constants(point, stepper):
    """`(rtols, smooth, friction)`: the error constants of both runs at each rtol."""
    p = FAMILY.grid[point]
    scene, x0, args = FAMILY.make(p)
    cls, order = campaign.STEPPERS[stepper]
    q = order / (order + 1)
    rtols = [r for r in campaign.RTOLS if order == 2 or r >= campaign.FIRST_ORDER_MIN_RTOL]
    out = []
    for run in _runs(scene, cls):
        row = []
        for rtol in rtols:
            sol = run(x0, args, rtol)
            assert sol.result == nj.RESULTS.successful, (point, stepper, rtol)
            k = int(sol.n_accepted)
            ts, xs = np.asarray(sol.ts[: k + 1]), np.asarray(sol.ys[: k + 1])
            row.append(FAMILY.error(p, ts, xs) / rtol**q)
        out.append(row)
    return rtols, *out


def main():
    lines = [
        "# The continuous-slip slider against its smooth law",
        "",
        "Error / rtol^q, whole horizon, default controller, semismooth Newton.",
        "",
        "| point | stepper | rtols | smooth law in f | through `Friction` |",
        "|---|---|---|---|---|",
    ]
    worst = {}
    for point in range(len(FAMILY.grid)):
        for stepper in campaign.STEPPERS:
            rtols, smooth, friction = constants(point, stepper)
            order = campaign.STEPPERS[stepper][1]
            worst[order] = max(worst.get(order, 0.0), max(smooth))
            cells = [
                f"{rtols[0]:.0e} .. {rtols[-1]:.0e}",
                " ".join(f"{c:.2f}" for c in smooth),
                " ".join(f"{c:.2f}" for c in friction),
            ]
            lines.append(f"| {point} | {stepper} | " + " | ".join(cells) + " |")
            print(lines[-1], flush=True)
    lines += [
        "",
        "Worst smooth constant per order: "
        + ", ".join(f"order {k}: {v:.2f}" for k, v in sorted(worst.items())),
    ]
    OUT.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
