"""``servogym tune`` checks what it returns before it writes files a drive loads."""

from __future__ import annotations

import json
import math

import typer
from typer.testing import CliRunner

from servogym.autotune import TuneConfig, run_study, tune
from servogym.autotune._cli import tune_command
from servogym.autotune._problem import Constraints, Outcome, TuneProblem
from servogym.autotune._report import export_names
from servogym.autotune._space import SearchSpace
from servogym.chips import get_chip
from servogym.sim import Scenario

from .helpers import SHORT_MOVES


def config(tmp_path, **kw) -> TuneConfig:
    base = dict(chip="TurboPMAC2", plant="rotary", out=tmp_path, budget=8, tuner="model-based",
                workers=2, moves=SHORT_MOVES["rotary"], check_candidates=1)  # fmt: skip
    return TuneConfig(**(base | kw))


def test_a_failing_check_withholds_the_hardware_files_unless_forced(tmp_path):
    # 89 degrees of phase margin: no set of this plant has it, so the check fails.
    _, summary = tune(config(tmp_path / "a", min_phase_margin_deg=89.0))
    out = tmp_path / "a"
    assert summary["check"]["passed"] is False
    assert any(f.startswith("reference: phase margin: ") and f.endswith("deg short)")
               for f in summary["check"]["failures"])  # fmt: skip
    formats = set(export_names(get_chip("TurboPMAC2")[0])) - {"json"}
    assert formats and set(summary["hardware_files_withheld"]) == formats
    names = {p.name for p in out.iterdir()}
    assert "best_params.json" in names and "bode.png" in names
    assert not any(n.startswith("best_params") and not n.endswith(".json") for n in names)
    doc = json.loads((out / "best_params.json").read_text())
    assert doc["notes"]["check"]["passed"] is False
    assert doc["notes"]["check"]["margins"]["phase_margin_deg"] < 89

    _, forced = tune(config(tmp_path / "b", min_phase_margin_deg=89.0, force=True))
    assert forced["check"]["passed"] is False and forced["hardware_files_withheld"] == []
    assert formats <= set(forced["files"])  # every export written


def test_a_passing_check_is_in_the_provenance_and_the_table(tmp_path):
    app = typer.Typer()
    app.command("tune")(tune_command)
    app.command("noop")(lambda: None)
    argv = ["tune", "--chip", "TurboPMAC2", "--plant", "rotary", "--budget", "8", "--tuner",
            "model-based", "--out", str(tmp_path), "--check-candidates", "2"]  # fmt: skip
    r = CliRunner().invoke(app, argv, env={"COLUMNS": "250"})
    summary = json.loads((tmp_path / "summary.json").read_text())
    check = summary["check"]
    assert r.exit_code == (0 if check["passed"] else 1), r.output
    assert "case (RK4 reference)" in r.output and "latency same_tick" in r.output
    assert "GM, PM: gain and phase margin" in r.output.replace("\n", " ")
    assert "gain margin" in r.output
    doc = json.loads((tmp_path / "best_params.json").read_text())
    assert doc["notes"]["check"] == json.loads(json.dumps(check))
    assert [c["name"] for c in check["cases"]][:1] == ["reference"]
    assert check["candidates"][-1]["trial"] == summary["best_trial"]


def test_margin_constraints_reach_optuna_and_the_outcome():
    scenario = Scenario("TurboPMAC2", "rotary", moves=SHORT_MOVES["rotary"], margins=True)
    problem = TuneProblem(scenario=scenario, space=SearchSpace.for_chip("TurboPMAC2"),
                          constraints=Constraints())  # fmt: skip
    result = run_study(problem, "random", 6, storage=None, batch_size=3)
    for t in result.trials:
        o = Outcome.from_attrs({**t.user_attrs["outcome"], "values": t.user_attrs["registers"]})
        c = t.constraints
        assert {"gain_margin", "phase_margin"} <= set(c)
        if math.isfinite(o.phase_margin_deg):
            assert c["phase_margin"] == min(max(30.0 - o.phase_margin_deg, -1000), 1000)


def test_outcomes_of_studies_from_before_the_margins_still_load():
    attrs = {"values": {"sgp": 1}, "cost": 1.0, "costs": [1.0], "n_diverged": 0,
             "max_following_error": 1.0, "saturation_fraction": 0.0, "rms_command": 0.1,
             "chatter": 0.0, "settling_time": 0.0}  # fmt: skip
    o = Outcome.from_attrs(attrs)
    assert math.isinf(o.gain_margin_db) and math.isinf(o.phase_margin_deg)
    assert o.to_attrs()["gain_margin_db"] is None
