"""The check before export: stress cases, margins, failures that name the check and the gap."""

from __future__ import annotations

import json
import math

import pytest
from typer.testing import CliRunner

from servogym.chips import get_chip
from servogym.cli import app
from servogym.sim import CheckLimits, Scenario, check_params
from servogym.sim._check import stress_cases

from .test_convergence import SETS

RUNNER = CliRunner()
FAST = CheckLimits(reference_substeps=4)  # the tests' reference: enough for the verdicts here


def safe(chip: str, plant: str):
    rec = SETS[f"{chip}/{plant}/default"]
    scenario = Scenario(chip, plant)
    return scenario, scenario.params(rec["values"])


@pytest.mark.parametrize("chip", ["MC2100", "MC58000", "TurboPMAC2", "6250"])
def test_stress_set_has_every_latency_the_load_and_friction_spreads(chip):
    scenario = Scenario(chip, "vertical-axis")
    cases = stress_cases(scenario, CheckLimits())
    family = get_chip(chip)[0]
    latencies = family.assumptions_type.CHOICES["loop_latency"]
    names = [c.name for c in cases]
    assert names[0] == "reference"
    assert {f"latency {x}" for x in latencies[1:]} <= set(names)
    load = {c.name: c.plant_changes for c in cases if c.name.startswith("load")}
    assert load == {"load -20%": {"payload_kg": pytest.approx(1.6)},
                    "load +20%": {"payload_kg": pytest.approx(2.4)}}  # fmt: skip
    friction = {c.name: c.plant_changes for c in cases if c.name.startswith("friction")}
    assert friction["friction -50%"] == {
        "viscous_friction_ns_per_m": pytest.approx(5.0),
        "coulomb_friction_n": pytest.approx(5.0),
    }
    assert friction["friction +50%"]["coulomb_friction_n"] == pytest.approx(15.0)


def test_a_spread_past_the_legal_range_stays_at_its_edge_and_says_so():
    scenario = Scenario("MC2100", "vertical-axis", plant_values={"payload_kg": 9.5})
    cases = {c.name: c for c in stress_cases(scenario, CheckLimits())}
    assert cases["load +20%"].plant_changes == {"payload_kg": 10.0}  # the range's top


def test_a_good_set_passes_with_margins_and_every_case(tmp_path):
    scenario, params = safe("6250", "rotary")
    report = check_params(params, scenario, FAST, bode_path=tmp_path / "bode.png")
    assert report.passed, report.failures
    assert report.margins.gain_margin_db >= 6 and report.margins.phase_margin_deg >= 30
    assert 0 < report.margins.gain_crossover_hz < report.margins.bandwidth_hz * 3
    assert not any(c.diverged for c in report.cases)
    assert (tmp_path / "bode.png").stat().st_size > 10_000
    doc = report.to_dict()
    json.dumps(doc)  # JSON-ready
    assert set(doc["margins_by_latency"]) == {"full_period", "same_tick", "half_period"}


def test_margin_failures_name_the_check_and_the_gap():
    scenario, params = safe("6250", "rotary")
    strict = CheckLimits(min_gain_margin_db=59.0, min_phase_margin_deg=89.0, reference_substeps=4)
    report = check_params(params, scenario, strict)
    assert not report.passed
    gm = report.margins.gain_margin_db
    line = next(f for f in report.failures if f.startswith("reference: gain margin"))
    assert line == f"reference: gain margin: {gm:.2f} dB < 59 dB ({59 - gm:.2f} dB short)"
    assert any(f.startswith("reference: phase margin") for f in report.failures)
    for c in report.cases:  # every case, each with its own margins
        assert any(f.startswith(f"{c.name}: gain margin: {c.margins.gain_margin_db:.2f} dB")
                   for f in report.failures)  # fmt: skip


def test_a_set_that_diverges_in_one_case_fails_naming_it():
    # Proportional only at full gain: a growing oscillation that trips the chip's own
    # motion error; the report names every case that diverged, with the time.
    scenario = Scenario("MC2100", "rotary", moves=Scenario("MC2100", "rotary").moves[:1])
    params = scenario.params(dict(kp=32767, kd=0, ki=0, kout=32767, derivative_time=1,
                                  position_error_limit=2000))  # fmt: skip
    report = check_params(params, scenario, FAST)
    assert not report.passed
    diverged = [c for c in report.cases if c.diverged]
    assert diverged
    for c in diverged:
        assert any(f.startswith(f"{c.name}: diverged ({c.divergence_reason}) at t = ")
                   for f in report.failures)  # fmt: skip
        assert math.isfinite(c.divergence_time_s)


def test_check_command_passes_and_fails_with_exit_codes(tmp_path):
    _, params = safe("6250", "rotary")
    family = get_chip("6250")[0]
    path = tmp_path / "set.json"
    path.write_text(family.export(params, "json"))
    out = tmp_path / "chk"
    r = RUNNER.invoke(app, ["check", str(path), "--plant", "rotary", "--out", str(out), "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert doc["passed"] and doc["chip_model"] == "6250"
    assert (out / "bode.png").exists() and json.loads((out / "check.json").read_text()) == doc
    r = RUNNER.invoke(app, ["check", str(path), "--plant", "rotary", "--out", str(out),
                            "--min-phase-margin", "89"])  # fmt: skip
    assert r.exit_code == 1
    assert "fail: reference: phase margin:" in r.output and "deg short" in r.output
    r = RUNNER.invoke(app, ["check", str(path), "--plant", "rotary", "--chip", "MC2100"])
    assert r.exit_code == 2
    assert "--chip MC2100 is a pmd model, but the file is a parker6k" in r.output
    r = RUNNER.invoke(app, ["check", str(path), "--plant", "rotary", "--min-gain-margin", "-1"])
    assert r.exit_code == 2
    # the option, not the library's argument min_gain_margin_db (issue 19)
    assert "--min-gain-margin must satisfy 0 <= --min-gain-margin <= 60; got " in r.output
