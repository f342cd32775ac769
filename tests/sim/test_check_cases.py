"""The check's verdict rests on every case: its margins, its following error, its saturation."""

from __future__ import annotations

import json
import math

import pytest

from servogym.sim import CheckLimits, Evaluator, MoveSpec, Scenario, check_params
from servogym.sim._check import following_error_limit, loop_margins, worst_margins
from servogym.sim._operating import holding_positions

from .test_convergence import SETS

FAST = CheckLimits(reference_substeps=4)


def tuned(chip: str, plant: str, **changes):
    rec = SETS[f"{chip}/{plant}/default"]
    scenario = Scenario(chip, plant)
    return scenario, scenario.params({**rec["values"], **changes})


def test_every_case_has_its_own_margins_and_the_worst_names_its_case():
    scenario, params = tuned("6250", "rotary")
    report = check_params(params, scenario, FAST)
    assert report.passed, report.failures
    for c in report.cases:
        assert c.margins is not None and c.margins.stable and c.passed
    # the load changes the loop: the cases' margins are not all the same
    assert len({round(c.margins.phase_margin_deg, 6) for c in report.cases}) > 1
    for key, w in report.worst.items():
        values = [getattr(c.margins, key) for c in report.cases]
        assert w["value"] == min(v for v in values if not math.isnan(v))
        case = next(c for c in report.cases if c.name == w["case"])
        assert getattr(case.margins, key) == w["value"]
    doc = json.loads(json.dumps(report.to_dict()))
    assert doc["worst"]["phase_margin_deg"]["case"] == report.worst["phase_margin_deg"]["case"]
    assert all(c["margins"]["stable"] for c in doc["cases"])


def test_a_robust_draw_with_a_small_margin_fails_naming_the_draw():
    scenario, params = tuned("6250", "rotary")
    loose = CheckLimits(reference_substeps=4, min_phase_margin_deg=1.0, min_gain_margin_db=1.0)
    base = check_params(params, scenario, loose)
    assert base.passed, base.failures
    # The phase margin of a draw with 3x the load, and a minimum just above it: only the
    # draw fails, and its line names it.
    heavy = {"load_inertia_kgm2": 2.7e-4}  # 3x the nominal 9e-5
    draw = check_params(params, scenario, loose, extra_plants=[heavy])
    pm = next(c for c in draw.cases if c.name == "plant draw 1").margins.phase_margin_deg
    assert pm < min(c.margins.phase_margin_deg for c in draw.cases[:-1])
    limit = (pm + min(c.margins.phase_margin_deg for c in draw.cases[:-1])) / 2
    strict = CheckLimits(reference_substeps=4, min_phase_margin_deg=limit, min_gain_margin_db=1)
    report = check_params(params, scenario, strict, extra_plants=[heavy])
    assert not report.passed
    assert {f.split(":")[0] for f in report.failures} == {"plant draw 1"}
    assert any(f.startswith(f"plant draw 1: phase margin: {pm:.2f} deg < ")
               for f in report.failures)  # fmt: skip
    assert report.worst["phase_margin_deg"] == {"value": pm, "case": "plant draw 1"}


def test_a_set_that_sags_under_gravity_fails_on_following_error_in_every_case():
    # The chip's defaults hold nothing against 3 kg on the arm: the error runs to thousands
    # of counts without any divergence; before, that "passed".
    scenario = Scenario("MC2100", "arm", plant_values={"payload_kg": 3.0})
    report = check_params(scenario.default_params(), scenario, FAST)
    assert not report.passed
    fe_lines = [f for f in report.failures if ": following error: " in f]
    assert {f.split(":")[0] for f in fe_lines} == {c.name for c in report.cases if not c.diverged}
    ref = report.cases[0]
    cpu = Evaluator(scenario).plant.io.counts_per_unit
    assert ref.following_error_limit == following_error_limit(scenario, cpu, FAST)
    assert ref.following_error_limit == pytest.approx(0.01 * 0.6 * cpu)  # 1 % of the move
    assert f"{ref.max_following_error:.0f} counts > " in fe_lines[0]


def test_a_saturated_but_stable_loop_fails_on_saturation():
    # A set that passes, with the output limited to 6 % of full scale (Ixx69): the linear
    # loop keeps its margins, but the motor lives at its limit.
    scenario, params = tuned("TurboPMAC2", "rotary", output_limit=2000)
    report = check_params(params, scenario, FAST)
    assert not report.passed
    assert report.cases[0].margins.stable
    sat = [f for f in report.failures if ": saturation: " in f]
    assert sat and sat[0].startswith("reference: saturation: ")
    assert "% of ticks at the motor limit > 5 % (" in sat[0] and sat[0].endswith("points over)")
    assert not any("margin" in f for f in report.failures)
    lenient = CheckLimits(reference_substeps=4, max_saturation=1.0, max_following_error=1e9)
    assert not any(": saturation: " in f
                   for f in check_params(params, scenario, lenient).failures)  # fmt: skip


def test_an_unstable_loop_fails_even_where_the_grid_saw_no_crossover():
    # MC2100 at 616 us with kp 400, kd 8000: the old grid read "GM unbounded, PM unbounded"
    # and passed it; its closed loop has poles outside the unit circle.
    scenario, params = tuned("MC2100", "rotary", sample_time_us=616, kp=400, kd=8000)
    report = check_params(params, scenario, FAST)
    assert not report.passed
    ref = report.cases[0]
    assert not ref.margins.stable
    assert ref.margins.gain_margin_db <= 0 and ref.margins.phase_margin_deg <= 0
    assert any(f.startswith("reference: unstable closed loop") for f in report.failures)


def test_the_arm_is_linearised_at_every_holding_point():
    scenario, params = tuned("MC2100", "arm")
    assert holding_positions(scenario.moves) == (0.0, 0.6)
    op = loop_margins(scenario, params)[scenario.chip.default_assumptions().loop_latency]
    assert op.points == (0.0, 0.6)
    a, b = (x.margins for x in op.analyses)
    assert a.phase_margin_deg != pytest.approx(b.phase_margin_deg, abs=1e-6)  # gravity's slope
    assert op.margins is op.analyses[op.worst].margins
    # a plant without gravity: the same loop at every point
    rot, rparams = tuned("MC2100", "rotary")
    rop = loop_margins(rot, rparams)[rot.chip.default_assumptions().loop_latency]
    x, y = (z.margins for z in rop.analyses)
    assert x.phase_margin_deg == pytest.approx(y.phase_margin_deg, rel=1e-6)


def test_holding_positions_follow_the_moves():
    moves = (MoveSpec(1.0, 1, 1), MoveSpec(-0.5, 1, 1), MoveSpec(-0.5, 1, 1))
    assert holding_positions(moves) == (0.0, 1.0, 0.5)


def test_worst_margins_of_no_case_is_empty():
    assert worst_margins([]) == {}


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"max_saturation": 1.5}, "max_saturation must satisfy 0 <= max_saturation <= 1"),
        ({"max_following_error": 0}, "max_following_error must be > 0 counts"),
        ({"max_following_error": math.inf}, "max_following_error must be > 0 counts"),
    ],
)
def test_bad_limits_name_the_parameter(kw, match):
    with pytest.raises(ValueError, match=match):
        CheckLimits(**kw)


def test_a_command_limit_below_what_the_moves_need_is_named():
    # Turbo PMAC's default Ixx69 (20480, 62.5 % of full scale) on the arm at 3 kg, whose
    # moves need about 75 % of the motor's peak: the check says so, in every case.
    scenario = Scenario("TurboPMAC2", "arm", plant_values={"payload_kg": 3.0})
    rec = SETS["TurboPMAC2/arm/default"]["values"]
    params = scenario.params({**rec, "output_limit": 20480})
    report = check_params(params, scenario, FAST)
    lines = [f for f in report.failures if ": command limit: " in f]
    assert {f.split(":")[0] for f in lines} == {c.name for c in report.cases}
    assert "limits the motor command to 62.5% of full scale" in lines[0]
    raised = check_params(scenario.params({**rec, "output_limit": 32767}), scenario, FAST)
    assert not any(": command limit: " in f for f in raised.failures)


def test_the_load_spread_stops_at_what_the_motor_moves():
    from servogym.plants import feasible_range
    from servogym.sim._check import stress_cases

    top = feasible_range("arm", "payload_kg")[1]
    scenario = Scenario("MC2100", "arm", plant_values={"payload_kg": top})
    cases = {c.name.split(" (")[0]: c for c in stress_cases(scenario, FAST)}
    up = cases["load +20%"]
    assert up.plant_changes == {"payload_kg": top}
    assert up.name == "load +20% (motor's max)"
    assert cases["load -20%"].plant_changes["payload_kg"] == pytest.approx(0.8 * top)
    # off the motor check (a scenario built to overload), the spread is the plain 20 %
    free = Scenario("MC2100", "arm", plant_values={"payload_kg": top}, motor_check=False)
    names = [c.name for c in stress_cases(free, FAST)]
    assert "load +20%" in names


def test_tuning_margins_are_the_worst_over_every_latency_as_the_check_has_them():
    import dataclasses

    from servogym.autotune import Constraints, SearchSpace, TuneProblem
    from servogym.sim._operating import severity

    scenario, params = tuned("TurboPMAC2", "rotary")
    every = Evaluator(dataclasses.replace(scenario, margins=True, margin_latencies="every"))
    own = Evaluator(dataclasses.replace(scenario, margins=True))
    asm = scenario.chip.default_assumptions()
    per_latency = loop_margins(scenario, params, type(asm).CHOICES["loop_latency"])
    worst = min((op.margins for op in per_latency.values()), key=severity)
    assert every.margins(params) == worst
    assert own.margins(params) == per_latency[asm.loop_latency].margins
    assert worst.phase_margin_deg < own.margins(params).phase_margin_deg
    problem = TuneProblem(scenario=scenario, space=SearchSpace.for_chip("TurboPMAC2"),
                          constraints=Constraints())  # fmt: skip
    assert problem.scenario.margins and problem.scenario.margin_latencies == "every"
    with pytest.raises(ValueError, match="margin_latencies must be 'own' or 'every'"):
        Scenario("MC2100", "rotary", margin_latencies="all")
