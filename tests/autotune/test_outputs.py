"""The main job's files: tuned set, exports that import back, trials, plots, summary; CLI."""

from __future__ import annotations

import csv
import dataclasses
import importlib
import json
import subprocess
import sys

import pytest
import typer
from typer.testing import CliRunner

from servogym.autotune import TuneConfig, read_param_file, run_study, tune
from servogym.autotune._cli import tune_command
from servogym.autotune._problem import MARGIN_CONSTRAINT_BOUND
from servogym.autotune._report import export_names
from servogym.chips._family import get_chip
from servogym.sim import Evaluator

from .helpers import SHORT_MOVES, short_problem


def importer(family):
    """The family's import_params (on the family object, or in its package)."""
    found = getattr(family, "import_params", None)
    if found is None:
        package = importlib.import_module(type(family).__module__.rsplit(".", 1)[0])
        found = package.import_params
    return found


@pytest.fixture(scope="module")
def tuned_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    config = TuneConfig(
        chip="MC2100", plant="rotary", out=out, budget=16, tuner="tpe", workers=2,
        moves=SHORT_MOVES["rotary"], batch_size=4,
    )  # fmt: skip
    result, summary = tune(config)
    return out, result, summary


def test_a_tuned_run_writes_every_output_file(tuned_run):
    out, result, summary = tuned_run
    family, _ = get_chip("MC2100")
    expected = {"study.journal", "trials.csv", "response.png", "convergence.png", "summary.json"}
    expected |= set(export_names(family).values())
    assert expected <= {p.name for p in out.iterdir()}
    assert {"best_params.json", "best_params.c", "best_params_host.txt"} <= expected
    for png in ("response.png", "convergence.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((out / "summary.json").read_text()) == json.loads(json.dumps(summary))
    assert summary["n_trials"] == summary["budget"] == 16
    assert summary["tuned"]["cost"] < summary["default"]["cost"]
    assert summary["tuned"]["cost"] == result.best.values[0]


def test_the_exports_of_a_tuned_run_import_back_to_the_same_set(tuned_run):
    out, result, _ = tuned_run
    family, model = get_chip("MC2100")
    for fmt, name in export_names(family).items():
        back = importer(family)((out / name).read_text(), fmt, model)
        assert back == result.best_params, fmt
    assert read_param_file(out / "best_params.json", model) == result.best_values


def test_best_params_json_carries_provenance_and_metrics(tuned_run):
    out, result, summary = tuned_run
    doc = json.loads((out / "best_params.json").read_text())
    assert doc["chip_model"] == "MC2100"
    assert doc["metrics"]["tuned"]["cost"] == summary["tuned"]["cost"]
    assert doc["metrics"]["default"]["cost"] == summary["default"]["cost"]
    assert doc["notes"]["tuner"] == "tpe" and doc["notes"]["best_trial"] == result.best.number
    assert doc["notes"]["scenario"]["plant"] == "rotary"


def test_trials_csv_has_every_trial_in_chip_units(tuned_run):
    out, result, _ = tuned_run
    rows = list(csv.DictReader((out / "trials.csv").open()))
    assert len(rows) == len(result.trials) == 16
    for row, t in zip(rows, result.trials, strict=True):
        assert int(row["number"]) == t.number
        assert float(row["cost"]) == t.values[0]
        assert int(row["kp"]) == t.user_attrs["registers"]["kp"]
        assert -1.0 <= float(row["u_kp"]) <= 1.0


def test_a_warm_start_is_evaluated_first_with_its_own_cost(tuned_run):
    out, result, _ = tuned_run
    warm = read_param_file(out / "best_params.json", "MC2100")
    problem = short_problem("MC2100", "rotary")
    again = run_study(problem, "tpe", 5, storage=None, warm_start=warm, batch_size=4)
    first = again.trials[0]
    assert first.user_attrs["kind"] == "warm_start"
    assert first.user_attrs["registers"] == result.best_values
    assert first.values[0] == result.best.values[0]
    assert again.best.values[0] <= result.best.values[0]


def test_multi_objective_keeps_a_pareto_front(tmp_path):
    config = TuneConfig(
        chip="MC2100", plant="rotary", out=tmp_path, budget=12, tuner="tpe",
        multi_objective=True, moves=SHORT_MOVES["rotary"], batch_size=4,
    )  # fmt: skip
    result, summary = tune(config)
    assert all(len(t.values) == 2 for t in result.trials)
    assert (tmp_path / "pareto.png").exists()
    front = summary["pareto_front"]
    assert front and result.best.number in {p["trial"] for p in front}


SAFE_SHORT_ROTARY = {
    "kp": 469,
    "ki": 10,
    "kd": 3261,
    "kvff": 4,
    "kaff": 6,
    "kout": 21409,
    "integration_limit": 383,
    "derivative_time": 1,
    "bias": 733,
}
"""A set that meets every constraint of ``short_problem()`` under the issue-13 loop, margins
included: cost 3.91, following error 46 of 209 counts, no saturation, gain margin 7.9 dB,
phase margin 31.2 degrees. Found by a 300-trial multivariate TPE study (seed 0) minimising
the constraint violations, then the cost (derivative_time searched over 1..3). Random sets
rarely are safe: none of 300 random or 300 TPE trials of ``run_study`` on that problem was
(derivative_time, 10 by default and searched up to 32767, must be small once the loop has
its latency)."""


def test_constraints_are_reported_to_optuna_and_decide_the_best_trial():
    # Margins computed on every trial, as `servogym tune` does (TuneConfig.problem).
    problem = short_problem(seed=1)
    problem = dataclasses.replace(
        problem, scenario=dataclasses.replace(problem.scenario, margins=True)
    )
    # The warm start gives the study one known-safe trial among random ones; on the
    # issue-13 loop twelve random sets are all unsafe (see SAFE_SHORT_ROTARY).
    result = run_study(problem, "random", 12, storage=None, batch_size=4,
                       warm_start=SAFE_SHORT_ROTARY)  # fmt: skip
    fe_limit = problem.following_error_limit(Evaluator(problem.scenario))
    limits = problem.constraints
    assert (limits.min_gain_margin_db, limits.min_phase_margin_deg) == (6.0, 30.0)
    bound = MARGIN_CONSTRAINT_BOUND
    for t in result.trials:
        c = t.constraints
        # The margin constraints (issue 13) are on by default, beside the three of the episode.
        assert set(c) == {"max_following_error", "saturation_fraction", "diverged",
                          "gain_margin", "phase_margin"}  # fmt: skip
        outcome = t.user_attrs["outcome"]
        assert c["max_following_error"] == outcome["max_following_error"] - fe_limit
        for name, minimum in (("gain_margin", 6.0), ("phase_margin", 30.0)):
            margin = outcome[f"{name}_{'db' if name == 'gain_margin' else 'deg'}"]
            expected = -bound if margin is None else min(max(minimum - margin, -bound), bound)
            assert c[name] == expected, (name, margin)
    feasible = [t for t in result.trials if all(v <= 0 for v in t.constraints.values())]
    assert 0 < len(feasible) < len(result.trials)
    assert all(v <= 0 for v in result.best.constraints.values())
    assert result.feasible
    assert result.best.number == min(feasible, key=lambda t: t.values[0]).number


@pytest.fixture()
def app():
    app = typer.Typer()
    app.command("tune")(tune_command)
    app.command("noop")(lambda: None)  # keeps "tune" a subcommand
    return app


def test_the_cli_runs_a_classical_tuner_and_prints_the_table(app, tmp_path):
    result = CliRunner().invoke(
        app,
        ["tune", "--chip", "MC2100", "--plant", "vertical-axis", "--budget", "12",
         "--tuner", "model-based", "--out", str(tmp_path), "--workers", "2",
         "--plant-param", "payload_kg=3"],
        env={"COLUMNS": "250"},
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "default" in result.output and "tuned" in result.output
    assert "best_params.c" in result.output
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["problem"]["plant_values"] == {"payload_kg": 3}
    assert summary["tuned"]["cost"] < summary["default"]["cost"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--tuner", "tpee"], "Did you mean tpe"),
        (["--fix", "kp"], "--fix takes NAME=VALUE"),
        (["--fix", "kp=40000"], "0 <= kp <= 32767"),
        (["--plant", "vertical-axis", "--plant-param", "payload=3"], "Did you mean payload_kg"),
        (["--robust-mode", "median"], "--robust-mode must be 'mean' or 'worst'"),
        (["--chip", "MC9999"], "unknown chip model 'MC9999'"),
    ],
)
def test_the_cli_explains_bad_options(app, tmp_path, args, message):
    base = {"--chip": "MC2100", "--plant": "rotary", "--budget": "4", "--out": str(tmp_path)}
    for i in range(0, len(args), 2):
        base[args[i]] = args[i + 1]
    argv = ["tune", *[x for kv in base.items() for x in kv]]
    result = CliRunner().invoke(app, argv)
    assert result.exit_code == 2, result.output
    assert message in " ".join(result.output.split()), result.output


def test_the_tune_path_does_not_import_torch(tmp_path):
    code = (
        "import sys\n"
        "from servogym.autotune import TuneConfig, tune\n"
        "from servogym.autotune._cli import tune_command\n"
        "from servogym.sim import MoveSpec\n"
        f"tune(TuneConfig(chip='MC2100', plant='rotary', out={str(tmp_path)!r}, budget=4,\n"
        "     moves=(MoveSpec(0.5, 40.0, 3000.0, 0.02),)))\n"
        "print(sorted(m for m in ('torch', 'stable_baselines3') if m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300
    )
    assert out.stdout.strip().splitlines()[-1] == "[]"
