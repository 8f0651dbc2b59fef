"""A fast slice of the reliability campaign (`python -m benchmarks.reliability`): every
family once, at two tolerances, judged by the campaign's own rule (a failure code, or an
error within C rtol^q that falls as rtol does). The relay and spiral families have their
grids in tests/test_filippov_trust.py; here each family runs its first grid point with one
stepper (the steppers rotate over the families) and semismooth Newton."""

import pytest

from benchmarks import reliability as campaign
from benchmarks.families import FAMILIES


SLICE = {
    "stick_slip": "Bathe",
    "ball_zeno": "BackwardEuler",
    "block_interval": "Trapezoidal",
    "block_cone": "Bathe",
    "rectifier": "EmbeddedBETR",
    "diode_bridge": "Trapezoidal",
    "chua": "Bathe",
    "super_twisting": "BackwardEuler",
}
RTOLS = (1e-4, 1e-5)


def _judged(name):
    family = FAMILIES[name]
    stepper = SLICE[name]
    scene, run = campaign.compiled_run(family, stepper, "SSN", "default")
    rows = []
    for rtol in RTOLS:
        row = campaign.run_one(family, scene, run, family.grid[0], rtol)
        row["rtol"] = rtol
        rows.append(row)
    return campaign.judge(family, campaign.STEPPERS[stepper][1], rows)


@pytest.mark.parametrize("name", list(SLICE))
def test_campaign_slice(name):
    rows = _judged(name)
    assert all(r["ok"] for r in rows), [r["result"] for r in rows]
    assert [r["verdict"] for r in rows] == ["pass"] * len(RTOLS), [
        (r["rtol"], r["error"], r["why"]) for r in rows
    ]


def test_the_rule_flags_a_wrong_answer():
    # The judge itself: an error that stays put as rtol falls, or one above C rtol^q, is a
    # silent wrong answer; a failure code is a stall; a small falling error passes.
    family = FAMILIES["relay"]
    rows = [
        dict(ok=True, rtol=1e-3, error=1e-2),
        dict(ok=True, rtol=1e-4, error=9e-3),  # does not fall
        dict(ok=False, rtol=1e-5, error=float("nan")),
        dict(ok=True, rtol=1e-6, error=1.0),  # above the bound
    ]
    verdicts = [r["verdict"] for r in campaign.judge(family, 1, rows)]
    assert verdicts == ["pass", "wrong", "stall", "wrong"]
    fine = [dict(ok=True, rtol=1e-3, error=1e-2), dict(ok=True, rtol=1e-4, error=1e-3)]
    assert [r["verdict"] for r in campaign.judge(family, 2, fine)] == ["pass", "pass"]


@pytest.mark.parametrize("stepper", ["Trapezoidal", "Bathe"])
def test_departures_from_a_face_keep_the_error_proportional(stepper):
    # Moreau's sweeping process: a box holds z at a face until u' turns, inside a step.
    # Without the departure term (`nivpjax._stepper.departure`) both schemes' estimates
    # were blind to it and their errors fell like rtol^(1/2), not rtol^(2/3): error /
    # (2 rtol^(2/3)) rose 0.6 -> 1.3 -> 2.0 -> 3.0 (Bathe, first point, rtol 1e-4 to 1e-7)
    # and 1.0 -> 5.2 on the fourth (A = 5). With it: one constant, 0.1-0.3.
    family = FAMILIES["sweeping"]
    scene, run = campaign.compiled_run(family, stepper, "SSN", "default")
    for point in (family.grid[0], family.grid[3]):
        ratios = []
        for rtol in (1e-4, 1e-5, 1e-6, 1e-7):
            row = campaign.run_one(family, scene, run, point, rtol)
            assert row["ok"], (point, rtol, row["result"])
            ratios.append(row["error"] / (family.C * rtol ** (2 / 3)))
        assert max(ratios) <= 1.0 and max(ratios) <= 2 * min(ratios), (point, ratios)
