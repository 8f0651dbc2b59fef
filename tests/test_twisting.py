"""Super-twisting (`nivpjax.scenes.super_twisting`) through its finite-time convergence
with the trapezoidal rule, judged as the reliability campaign judges it
(`benchmarks.reliability`), at the steps and at `t_eval`.

- The steps: error within C rtol^q and falling as rtol does. Before the trapezoidal
  estimate stopped adding its defect term (see `theta_error`), rtol 1e-4 and 1e-6 ended
  `successful` at 1.12 and 1.08 times the bound: steps approaching a crossing of the
  surface, where the rate's sqrt|sigma| has its singularity, accepted at up to 5 times
  their tolerance, and each crossing multiplies a timing error by 2 k2 / |sigma'|.
- `t_eval` after the convergence (a second-order sliding mode, sigma = sigma' = 0): as
  right as the steps around each output time (the campaign's ratio at most 2). The
  trapezoidal rule's selection rings from step to step there (w1 = 2 w_mean - w0); the
  cubic through the end rates of nu' = -k2 w was 400 times the steps' error before the
  interpolant took the second-order equivalent control at the ends
  (`nivpjax._held.second_order_ends`).

And the trapezoidal rule's block on a plane (cone friction) stopping inside a step, at
`t_eval` (the campaign's other ratio far above 2: 129)."""

import numpy as np
import pytest

from benchmarks import reliability as campaign
from benchmarks.families import FAMILIES


FAMILY = FAMILIES["super_twisting"]
RTOLS = (1e-4, 1e-5, 1e-6)


@pytest.fixture(scope="module")
def rows():
    scene, run = _sliding_run("Trapezoidal")
    out = []
    for rtol in RTOLS:
        row = campaign.run_one(FAMILY, scene, run, FAMILY.grid[0], rtol)
        row["rtol"] = rtol
        out.append(row)
    return campaign.judge(FAMILY, 2, out)


def test_steps_meet_the_campaign_rule(rows):
    assert all(r["ok"] for r in rows), [r["result"] for r in rows]
    assert [r["verdict"] for r in rows] == ["pass"] * len(RTOLS), [
        (r["rtol"], r["error"], r["ratio"], r["why"]) for r in rows
    ]
    # Not at the bound's edge: measured 0.48, 0.63, 0.80 (1.12, 0.99, 1.08 before).
    assert max(r["ratio"] for r in rows) <= 0.9, [r["ratio"] for r in rows]


def test_t_eval_as_right_as_the_steps(rows):
    ratios = np.array([r["teval_ratio"] for r in rows])
    assert np.all(ratios <= 2.0), ratios
    assert np.all([r["outside"] == 0.0 for r in rows]), [r["outside"] for r in rows]


# (grid point, rtol) of the second-order sliding runs at t_eval: the campaign's quick slice
# (point 0) and its other point (c = 3, L = 5).
SLIDING = ((0, 1e-3), (0, 1e-5), (0, 1e-6), (1, 1e-3), (1, 1e-4))


@pytest.mark.parametrize("stepper", ["Bathe", "Trapezoidal"])
def test_t_eval_in_the_second_order_sliding_mode(stepper):
    # After the convergence sigma = sigma' = 0, and sigma' = nu + d(t) + c x2 is a
    # constraint on the differential states that the steps keep (nu = -d - c x2) and a
    # cubic through the ends does not: nu follows the disturbance 0.3 sin 5t, and over the
    # long steps of the sliding mode the cubic is off by h^4 |nu^(4)| / 384. The t_eval
    # ratios before the interpolant was moved onto sigma = sigma' = 0
    # (`_held.on_second_order_surface`): Bathe 20.3, 2.4, 4.1, 2197, 4687 at `SLIDING`;
    # the trapezoidal rule 2.9 at point 0, rtol 1e-3 (it stalls on point 1 with a failure
    # code). Without the step onto sigma = 0 first, sqrt|sigma| turned the interpolant's
    # sigma ~ 1e-13 into 1e-6 of sigma' (Bathe, point 0, rtol 1e-6: 14.6).
    scene, run = _sliding_run(stepper)
    cases = SLIDING if stepper == "Bathe" else SLIDING[:1]
    rows = [campaign.run_one(FAMILY, scene, run, FAMILY.grid[g], rtol) for g, rtol in cases]
    assert all(r["ok"] for r in rows), [r["result"] for r in rows]
    ratios = [r["teval_ratio"] for r in rows]
    assert max(ratios) <= 2.0, ratios
    assert all(r["outside"] == 0.0 for r in rows), [r["outside"] for r in rows]


_SLIDING = {}


def _sliding_run(stepper):
    if stepper not in _SLIDING:
        _SLIDING[stepper] = campaign.compiled_run(FAMILY, stepper, "SSN", "default", outputs=True)
    return _SLIDING[stepper]


@pytest.mark.parametrize("rtol", [1e-3, 1e-5])
def test_t_eval_across_a_stop_inside_a_step(rtol):
    # The campaign's block on a plane with cone friction, trapezoidal rule: the block stops
    # inside a step (rtol 1e-5: [0.7496, 0.7609], stop at 0.7598). The stage's multiplier
    # at the step's end is its average over the step (0.9 mu g), not the stick's zero
    # force, and the cubic through the end rates left the block moving after its stop:
    # `t_eval` ratio 14.6 and 129 before (the end's selection taken from the held phase,
    # the rows at rest at the end following the flow from the start up to the stop).
    family = FAMILIES["block_cone"]
    scene, run = _cone_run()
    row = campaign.run_one(family, scene, run, family.grid[0], rtol)
    assert row["ok"], row["result"]
    assert row["teval_ratio"] <= 2.0, row["teval_ratio"]
    assert row["outside"] <= 1e-12, row["outside"]


_CONE = {}


def _cone_run():
    if not _CONE:
        _CONE["run"] = campaign.compiled_run(
            FAMILIES["block_cone"], "Trapezoidal", "SSN", "default", outputs=True
        )
    return _CONE["run"]
