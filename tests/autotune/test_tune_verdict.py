"""What ``servogym tune`` writes when its best trial fails the check, and what it reports."""

from __future__ import annotations

import csv
import dataclasses
import io
import json

import pytest
import typer
from typer.testing import CliRunner

from servogym.autotune import TuneConfig, tune
from servogym.autotune._cli import fallback_line, summary_heading, tune_command
from servogym.autotune._report import plant_description
from servogym.sim import _check
from servogym.sim._check import CheckReport

from .helpers import SHORT_MOVES


def config(tmp_path, **kw) -> TuneConfig:
    base = dict(chip="TurboPMAC2", plant="rotary", out=tmp_path, budget=8, tuner="model-based",
                workers=2, moves=SHORT_MOVES["rotary"], check_candidates=8)  # fmt: skip
    return TuneConfig(**(base | kw))


def app() -> typer.Typer:
    a = typer.Typer()
    a.command("tune")(tune_command)
    a.command("noop")(lambda: None)
    return a


@pytest.fixture
def best_fails(monkeypatch):
    """The check fails the first set it is given (the best trial) and passes the rest."""
    real = _check.check_params  # TuneProblem.check calls it
    seen = []

    def fake(params, scenario, limits, **kw):
        report = real(params, scenario, limits, **kw)
        seen.append(params)
        if len(seen) == 1:
            return dataclasses.replace(report, passed=False,
                                       failures=("reference: phase margin: 20.00 deg < 30 deg "
                                                 "(10.00 deg short)",))  # fmt: skip
        return dataclasses.replace(report, passed=True, failures=())

    monkeypatch.setattr(_check, "check_params", fake)
    return seen


def test_a_fallback_to_another_trial_says_it_is_worse_and_by_how_much(tmp_path, best_fails):
    out = tmp_path / "run"
    r = CliRunner().invoke(app(), ["tune", "--chip", "TurboPMAC2", "--plant", "rotary",
                                   "--budget", "8", "--tuner", "model-based", "--out", str(out),
                                   "--check-candidates", "8"],
                           env={"COLUMNS": "250"})  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())
    fb = summary["check"]["fallback"]
    assert fb is not None, summary["check"]["candidates"]
    assert r.exit_code == 0, r.output
    first, chosen = summary["check"]["candidates"][0], summary["check"]["candidates"][-1]
    assert fb["best_trial"] == first["trial"] and fb["written_trial"] == chosen["trial"]
    assert summary["best_trial"] == chosen["trial"] != first["trial"]
    assert fb["cost_ratio"] == pytest.approx(fb["written_cost"] / fb["best_cost"])
    assert fb["written_cost"] >= fb["best_cost"]  # candidates come cheapest first
    assert fb["best_failures"] == [first["failures"][0]]
    assert "warning: the best trial" in r.output
    assert f"{fb['cost_ratio']:.3g}x the best trial's cost" in r.output.replace("\n", "")


def test_fallback_candidates_are_only_trials_that_met_every_constraint(tmp_path, best_fails):
    result, summary = tune(config(tmp_path))
    numbers = [c["trial"] for c in summary["check"]["candidates"]]
    by_number = {t.number: t for t in result.trials}
    for n in numbers[1:]:
        assert all(v <= 0 for v in by_number[n].constraints.values())
    costs = [c["cost"] for c in summary["check"]["candidates"][1:]]
    assert costs == sorted(costs)


def test_no_passing_candidate_exits_1_naming_the_best_candidates_failures(tmp_path):
    out = tmp_path / "run"
    r = CliRunner().invoke(app(), ["tune", "--chip", "TurboPMAC2", "--plant", "rotary",
                                   "--budget", "8", "--tuner", "model-based", "--out", str(out),
                                   "--min-phase-margin", "89"],
                           env={"COLUMNS": "250"})  # fmt: skip
    assert r.exit_code == 1, r.output
    summary = json.loads((out / "summary.json").read_text())
    check = summary["check"]
    assert not check["passed"] and check["fallback"] is None
    assert summary["best_trial"] == check["candidates"][0]["trial"]
    text = r.output.replace("\n", "")
    assert "check failed:" in text and "deg short" in text
    for line in check["failures"]:
        assert line in text
    assert not any(p.suffix in (".c", ".pmc") for p in out.iterdir())


def test_trials_csv_has_margins_and_the_constraints_each_trial_failed(tmp_path):
    result, _ = tune(config(tmp_path, check=False))
    rows = list(csv.DictReader(io.StringIO((tmp_path / "trials.csv").read_text())))
    for col in ("failed_constraints", "n_unstable", "gain_margin_db", "phase_margin_deg",
                "delay_margin_s", "bandwidth_hz"):  # fmt: skip
        assert col in rows[0]
    by_number = {t.number: t for t in result.trials}
    scored = [r for r in rows if r["cost"]]
    assert scored
    for row in scored:
        t = by_number[int(row["number"])]
        failed = {k for k, v in t.constraints.items() if v > 0}
        assert set(filter(None, row["failed_constraints"].split(";"))) == failed
        assert (row["feasible"] == "True") == (not failed)
        o = t.user_attrs["outcome"]
        assert row["phase_margin_deg"] == ("" if o["phase_margin_deg"] is None
                                           else str(o["phase_margin_deg"]))  # fmt: skip
        assert row["bandwidth_hz"] != "" or o["bandwidth_hz"] is None


def test_the_closing_heading_names_the_plant_it_ran():
    problem = {"n_plants": 1, "robust_mode": "mean", "plant_values": {"payload_kg": 3.0}}
    summary = {"problem": problem, "chip_model": "MC2100", "plant": "arm", "tuner": "tpe",
               "n_trials": 5}  # fmt: skip
    assert "(plant payload_kg=3)" in summary_heading(summary)
    assert plant_description({**problem, "plant_values": {}}) == "nominal plant"
    robust = {**problem, "n_plants": 4, "plant_values": {},
              "plant_ranges": {"payload_kg": [0.5, 2.0]}}  # fmt: skip
    assert plant_description(robust) == "mean over 4 plant instances with payload_kg in [0.5, 2]"


def test_fallback_line_is_none_without_a_fallback():
    report = {"fallback": None}
    assert fallback_line(report) is None
    assert CheckReport.__dataclass_fields__["fallback"].default is None
