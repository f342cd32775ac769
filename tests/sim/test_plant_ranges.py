"""Scenario.plant_ranges: validated, drawn from, and refused when the motor cannot move it."""

import numpy as np
import pytest

from servogym.autotune import SearchSpace, TuneProblem
from servogym.plants import MotorFeasibilityError, PlantParameterError
from servogym.sim import Scenario


def test_robust_draws_come_from_the_given_range():
    sc = Scenario("MC2100", "arm", plant_ranges={"payload_kg": (1.0, 2.0)})
    problem = TuneProblem(scenario=sc, space=SearchSpace.for_chip("MC2100"), n_plants=8, seed=3)
    draws = problem.plant_instances()
    assert all(1.0 <= d["payload_kg"] <= 2.0 for d in draws)
    assert len({d["payload_kg"] for d in draws}) == 8
    # The nominal plant stays nominal; a random scenario draws inside the range too.
    assert problem.nominal_plant()["payload_kg"] == 0.5
    rnd = Scenario("MC2100", "arm", randomise=True, plant_ranges={"payload_kg": (1.0, 2.0)})
    rng = np.random.default_rng(0)
    assert all(1.0 <= rnd.draw_plant(rng)["payload_kg"] <= 2.0 for _ in range(20))


def test_the_issues_loads_are_refused_in_one_line():
    cases = [
        ("arm", {"plant_values": {"payload_kg": 4.6}}, r"payload_kg=4\.6 \(plant_values"),
        ("rotary", {"plant_ranges": {"load_inertia_kgm2": (1e-5, 8e-4)}},
         r"load_inertia_kgm2=0\.0008 \(a plant_ranges end"),
        ("rotary", {"plant_values": {"load_inertia_kgm2": 2.6e-3}}, r"load_inertia_kgm2=0\.0026"),
    ]  # fmt: skip
    for plant, kw, match in cases:
        with pytest.raises(MotorFeasibilityError, match=match) as info:
            Scenario("MC2100", plant, **kw)
        text = str(info.value)
        assert "\n" not in text and "N*m at the motor shaft" in text and "2 N*m peak" in text


def test_a_robust_scenario_refuses_an_unmovable_corner_of_its_draws():
    # 3 kg alone is movable; with the default friction draws (up to 2 N*m at the link) not.
    Scenario("MC2100", "arm", plant_values={"payload_kg": 3.0})
    with pytest.raises(MotorFeasibilityError, match="coulomb_friction_nm=2"):
        Scenario("MC2100", "arm", randomise=True, plant_ranges={"payload_kg": (0.5, 3.0)})
    Scenario("MC2100", "arm", randomise=True, plant_ranges={
        "payload_kg": (0.5, 3.0), "coulomb_friction_nm": (0.01, 0.2)})  # fmt: skip


@pytest.mark.parametrize(
    ("ranges", "values", "match"),
    [
        ({"payload": (1, 2)}, {}, r"Did you mean payload_kg"),
        ({"payload_kg": (2, 1)}, {}, r"payload_kg=2:1 must have low <= high"),
        ({"payload_kg": (0, 1)}, {}, r"payload_kg=0:1 must lie inside .*0\.05 <= payload_kg <= 5"),
        ({"payload_kg": (1, 2)}, {"payload_kg": 1.5}, r"also held at a fixed value"),
    ],
)
def test_illegal_ranges_name_the_rule_and_range(ranges, values, match):
    with pytest.raises(PlantParameterError, match=match):
        Scenario("MC2100", "arm", plant_values=values, plant_ranges=ranges)


def test_a_stress_case_may_overload():
    sc = Scenario("MC2100", "arm", plant_values={"payload_kg": 4.6}, motor_check=False)
    assert sc.plant_values["payload_kg"] == 4.6
