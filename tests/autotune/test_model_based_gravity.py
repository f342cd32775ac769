"""The model-based design under gravity: it holds the load first, then identifies.

At both ends of each family's movable load range (``servogym.plants.feasible_range``), for
the four chips of issue 18, the design (the 9 simulations a default tune starts from) must
not diverge and must give a finite, sane cost. Known exceptions are marked: Turbo PMAC's
default output limit (Ixx69 = 20480, 62.5 % of full scale, not a searched register) is below
what a load at the top of the range needs (80 %), so every candidate trips; and a two-mass
load at 1e-3 kg*m^2 (resonance 17 Hz) is not the rigid axis the design assumes.
"""

import math

import pytest

from servogym.autotune import Constraints, SearchSpace, TuneProblem
from servogym.autotune._job import DESIGN_BUDGET, run_study
from servogym.plants import PLANTS, feasible_range
from servogym.sim import Evaluator, Scenario

CHIPS = ["MC2100", "MC58000", "TurboPMAC2", "6250"]
KNOWN = {
    ("TurboPMAC2", "arm", "heaviest"): "default Ixx69 output limit 62.5 % < the 80 % needed",
    ("TurboPMAC2", "rotary", "heaviest"): "default Ixx69 output limit 62.5 % < the 80 % needed",
}
WEAK = {("two-mass", "heaviest")}  # finite, not diverged, but not better than the defaults


def ends(plant):
    fam = PLANTS[plant]
    lo, hi = feasible_range(fam, fam.load_param)
    return {"lightest": lo, "heaviest": hi}


def design(chip, plant, end):
    fam = PLANTS[plant]
    sc = Scenario(chip, plant, plant_values={fam.load_param: ends(plant)[end]})
    problem = TuneProblem(
        scenario=sc, space=SearchSpace.for_chip(sc.chip_model), constraints=Constraints()
    )
    default = Evaluator(sc).evaluate(sc.default_params()).cost
    result = run_study(problem, "model-based", DESIGN_BUDGET, storage=None, n_workers=1)
    experiments = [t.user_attrs["experiment"] for t in result.trials
                   if t.user_attrs.get("kind") == "experiment"]  # fmt: skip
    return result, default, experiments


def check(chip, plant, end):
    if (chip, plant, end) in KNOWN:
        pytest.xfail(KNOWN[chip, plant, end])
    result, default, experiments = design(chip, plant, end)
    assert not any(e["diverged"] for e in experiments), experiments
    cost = result.best.values[0]
    assert math.isfinite(cost) and cost < 100, cost  # no divergence penalty, no capped move
    if (plant, end) not in WEAK:
        assert cost < max(5.0, default), (cost, default)
    return result, experiments


@pytest.mark.parametrize("end", ["lightest", "heaviest"])
@pytest.mark.parametrize("chip", CHIPS)
def test_arm_design_holds_gravity_at_both_ends(chip, end):
    _result, experiments = check(chip, "arm", end)
    # The hold identifies the gravity command: (m_link/2 + m_payload) * L * g / n at 0 rad,
    # as a fraction of the 2 N*m peak (the moves go up to 0.6 rad, cos 0.83: a little less).
    v = {**PLANTS["arm"].nominal(), "payload_kg": ends("arm")[end]}
    hold = (v["link_mass_kg"] / 2 + v["payload_kg"]) * v["link_length_m"] * 9.81 / 10 / 2.0
    fitted = experiments[0]["gravity_cmd"] / 32768
    assert 0.8 * hold < fitted < 1.05 * hold, (fitted, hold)


def test_arm_at_3kg_no_longer_diverges():
    # Issue 18: at payload_kg=3 every identification move diverged (10 %/20 % limits).
    sc = Scenario("MC2100", "arm", plant_values={"payload_kg": 3.0})
    problem = TuneProblem(scenario=sc, space=SearchSpace.for_chip("MC2100"))
    result = run_study(problem, "model-based", DESIGN_BUDGET, storage=None, n_workers=1)
    assert result.best.values[0] < 5.0  # measured 2.10; the chip defaults cost 16.1


@pytest.mark.parametrize("end", ["lightest", "heaviest"])
@pytest.mark.parametrize("chip", CHIPS)
def test_vertical_axis_design_at_both_ends(chip, end):
    check(chip, "vertical-axis", end)


@pytest.mark.slow
@pytest.mark.parametrize("end", ["lightest", "heaviest"])
@pytest.mark.parametrize("chip", CHIPS)
@pytest.mark.parametrize("plant", ["rotary", "two-mass"])
def test_horizontal_axes_design_at_both_ends(plant, chip, end):
    check(chip, plant, end)
