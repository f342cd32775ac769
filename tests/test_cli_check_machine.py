"""`servogym check` of a multi-axis parameter file on a multi-axis plant: every chip family on
both machines, the exit codes, the table, check.json and the refusals."""

from __future__ import annotations

import dataclasses
import functools
import json

import pytest
from typer.testing import CliRunner

import servogym.sim._check as check_module
import servogym.sim._multieval as multieval
from servogym.chips._axes import save_axes
from servogym.cli import app
from tests.sim.test_multicheck import CROSSOVER_HZ, MODELS, SHORT, designed_sets

runner = CliRunner()


@pytest.fixture
def quick(monkeypatch):
    """The plants' small tasks and 4 RK4 substeps, so that each run takes seconds (the
    default tasks at 32 substeps take 15 s to a minute per machine)."""
    monkeypatch.setattr(multieval, "DEFAULT_TASKS", SHORT)
    quick_limits = functools.partial(check_module.CheckLimits, reference_substeps=4)
    monkeypatch.setattr(check_module, "CheckLimits", quick_limits)


@pytest.mark.parametrize("plant", ["xy-stage", "two-link-arm"])
@pytest.mark.parametrize("family", sorted(MODELS))
def test_every_family_passes_a_designed_set_on_both_machines(quick, tmp_path, plant, family):
    model = MODELS[family]
    path = save_axes(tmp_path / "axes.txt", designed_sets(plant, model, CROSSOVER_HZ[family]))
    result = runner.invoke(app, ["check", str(path), "--plant", plant, "--chip", model])
    assert result.exit_code == 0, result.output
    assert "check passed" in result.output and "stress cases" in result.output
    doc = json.loads((tmp_path / "axes_check" / "check.json").read_text())
    assert doc["passed"] and doc["stable"] and doc["chip_model"] == model
    assert doc["axes"] == (["x", "y"] if plant == "xy-stage" else ["shoulder", "elbow"])
    assert doc["limits"]["reference_substeps"] == 4
    for loop in doc["loops"]:
        assert loop["margins"]["gain_margin_db"] >= 6
        assert loop["margins"]["phase_margin_deg"] >= 30


def test_destabilising_gains_exit_1_naming_the_reason(quick, tmp_path):
    sets = designed_sets("xy-stage", "TurboPMAC2", 40.0)
    bad = dataclasses.replace(sets[1], proportional_gain=sets[1].proportional_gain * 30,
                              derivative_gain=0)  # fmt: skip
    path = save_axes(tmp_path / "axes.json", [sets[0], bad], "json")
    out = tmp_path / "report"
    result = runner.invoke(app, ["check", str(path), "--plant", "xy-stage", "--out", str(out),
                                 "--json"])  # fmt: skip
    assert result.exit_code == 1
    doc = json.loads(result.output)
    assert not doc["passed"] and not doc["stable"]
    assert any("unstable closed loop" in f for f in doc["failures"])
    assert json.loads((out / "check.json").read_text())["failures"] == doc["failures"]


def test_the_files_assumptions_are_checked(quick, tmp_path):
    """A file that records loop_latency same_tick is checked with it as the reference."""
    from servogym.chips._family import get_chip

    chip, _ = get_chip("6250")
    asm = dataclasses.replace(chip.default_assumptions(), loop_latency="same_tick")
    sets = designed_sets("xy-stage", "6250", 40.0)
    path = save_axes(tmp_path / "axes.txt", sets, None, asm)
    result = runner.invoke(app, ["check", str(path), "--plant", "xy-stage", "--json"])
    assert result.exit_code == 0, result.output
    cases = json.loads(result.output)["cases"]
    assert cases[0]["name"] == "reference" and cases[0]["loop_latency"] == "same_tick"


def test_refusals_name_the_option(tmp_path):
    sets = designed_sets("xy-stage", "6250", 40.0)
    path = save_axes(tmp_path / "axes.txt", sets)
    result = runner.invoke(app, ["check", str(path), "--plant", "xy-stage", "--chip", "MC2100"])
    assert result.exit_code != 0 and "MC2100" in result.output
    result = runner.invoke(app, ["check", str(path), "--plant", "xy-stage",
                                 "--plant-param", "payload_kg=-1"])  # fmt: skip
    assert result.exit_code != 0 and "payload_kg" in result.output
    one = save_axes(tmp_path / "one.txt", sets[:1])
    result = runner.invoke(app, ["check", str(one), "--plant", "two-link-arm"])
    assert result.exit_code != 0 and "has 2 axes" in result.output
