"""A campaign family for issue 33's leftover: the elliptic bowl with Coulomb friction, against
a reference without nivpjax (`ellipse_friction_bowl_state`: the constrained Lagrangian in the
ellipse's angle parameter with the sliding friction force, its stops located as events).

Kept out of `benchmarks/families.py` while another change works there. To register it, add
`BOWL_ELLIPSE_FRICTION` to `FAMILIES` in `families.py` (after `BOWL_ELLIPSE`), importing
it from here; or fold it in: `_bowl_friction_error`'s ellipse branch can call
`ellipse_friction_bowl_state` for every mu (at mu = 0 it reproduces `ellipse_bowl_state`
to 1e-11).

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.families_bowl_extra [--quick]

runs the family alone through the reliability campaign's runner and judge (SSN, the default
controller, every stepper) and writes benchmarks/results/bowl_ellipse_friction.md.
"""

import sys
import time
from pathlib import Path

from .families import Family, _bowl_friction_make, _max_error


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
from _references_mechanics import ellipse_friction_bowl_state  # noqa: E402


def _ellipse_friction_error(p, ts, xs):
    # The whole state: no impact, velocities are continuous (kinks at the stops).
    exact, _ = ellipse_friction_bowl_state(
        ts, p["phi0"], p["v0"] / p["a"], p["a"], 1.0, 9.81, p["mu"]
    )
    return _max_error(xs[:, :4], exact)


BOWL_ELLIPSE_FRICTION = Family(
    "bowl_ellipse_friction",
    "Contact(friction=mu) on an ellipse: friction on a wall of varying curvature",
    "A ball sliding with Coulomb friction on the wall of an elliptic bowl (semi-axes a x 1) "
    "to a stick",
    _bowl_friction_make,
    (
        # Thrown, turns back where the wall is too steep, sticks at t = 1.8845.
        {"a": 1.5, "mu": 0.3, "phi0": 0.0, "v0": 3.0},
        # A narrow bowl: turns back twice, sticks at t = 1.7489.
        {"a": 0.7, "mu": 0.2, "phi0": 0.0, "v0": 2.0},
        # Released from rest high on the wall, slides down, sticks at t = 1.4173.
        {"a": 1.5, "mu": 0.2, "phi0": 0.8, "v0": 0.0},
    ),
    2.0,
    _ellipse_friction_error,
    5.0,
)


def main():
    from .reliability import QUICK_RTOLS, RTOLS, STEPPERS, campaign, summary, wrong_list

    quick = "--quick" in sys.argv
    start = time.perf_counter()
    rows = campaign(
        [BOWL_ELLIPSE_FRICTION],
        list(STEPPERS),
        ["SSN"],
        ["default"],
        QUICK_RTOLS if quick else RTOLS,
        slice(None),
    )
    minutes = (time.perf_counter() - start) / 60
    table = summary(rows, [BOWL_ELLIPSE_FRICTION])
    header = (
        f"The elliptic bowl with friction alone through the campaign (SSN, default control, "
        f"rtols {', '.join(f'{r:.0e}' for r in (QUICK_RTOLS if quick else RTOLS))}, every "
        f"grid point): {minutes:.0f} min."
    )
    text = f"{header}\n\n{table}\n\n{wrong_list(rows)}\n"
    (Path(__file__).resolve().parent / "results" / "bowl_ellipse_friction.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
