"""CLI conventions: --version, python -m, completion, --json everywhere, defaults in help,
units in simulate's table, library logging rendered by the CLI."""

from __future__ import annotations

import dataclasses
import json
import logging
import re
import subprocess
import sys

import pytest
import typer
from typer.testing import CliRunner

import servogym
from servogym.chips.pmd import PMDParams, to_json
from servogym.cli import METRIC_UNITS, app, setup_logging
from servogym.sim._metrics import EpisodeMetrics

runner = CliRunner()
COMMANDS = sorted(typer.main.get_command(app).commands)


def test_version_from_the_command_and_python_m():
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0 and result.output.strip() == f"servogym {servogym.__version__}"
    out = subprocess.run([sys.executable, "-m", "servogym", "--version"], capture_output=True,
                         text=True, check=True, timeout=300)  # fmt: skip
    assert out.stdout.strip() == f"servogym {servogym.__version__}"


def test_shell_completion_is_offered():
    result = runner.invoke(app, ["--help"])
    assert "--install-completion" in result.output and "--show-completion" in result.output


@pytest.mark.parametrize("command", [c for c in COMMANDS if c != "check"])
def test_every_command_that_prints_results_has_json(command):
    params = typer.main.get_command(app).commands[command].params
    assert "--json" in {o for p in params for o in getattr(p, "opts", [])}


@pytest.mark.parametrize("command", COMMANDS)
def test_help_shows_defaults_and_loses_no_text_to_markup(command):
    result = runner.invoke(app, [command, "--help"], env={"COLUMNS": "250"})
    assert result.exit_code == 0
    # "Evaluation threads ." was "Evaluation threads [default: all cores]." with the
    # [default: ...] eaten by rich markup
    assert not re.search(r"[A-Za-z] \.\s", result.output)


def test_tune_help_shows_the_computed_defaults():
    out = runner.invoke(app, ["tune", "--help"], env={"COLUMNS": "250"}).output
    out = " ".join(out.split())  # click wraps the help column to the longest option's width
    for text in ("all cores", "OUT/study.journal", "servogym-<OUT name>", "1 % of the longest"):
        assert text in out


def test_simulate_table_has_a_unit_for_every_metric(tmp_path):
    fields = [f.name for f in dataclasses.fields(EpisodeMetrics) if f.name != "dt"]
    assert list(METRIC_UNITS) == fields
    result = runner.invoke(app, ["simulate", "--plant", "rotary", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "counts*s" in result.output and "unit" in result.output


def test_export_json(tmp_path):
    path = tmp_path / "p.json"
    path.write_text(to_json(PMDParams(model="MC2100", kp=60)))
    result = runner.invoke(app, ["export", str(path), "--format", "cmotion", "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.output)
    assert doc["format"] == "cmotion" and doc["chip_model"] == "MC2100"
    assert "PMDSetKp" in doc["text"]


def test_tune_json_and_the_note_when_a_classical_tuner_stops_early(tmp_path):
    args = ["tune", "--chip", "MC2100", "--plant", "rotary", "--workers", "1"]
    result = runner.invoke(app, [*args, "--budget", "3", "--out", str(tmp_path / "a"), "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["n_trials"] == 3 and summary["tuner"] == "safe"  # the default tuner
    result = runner.invoke(app, [*args, "--budget", "40", "--tuner", "model-based",
                                 "--out", str(tmp_path / "b")], terminal_width=300)  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "note: the model-based procedure finished after 9 of 40 evaluations" in result.output


def test_library_logging_is_rendered_by_rich_on_stderr(capsys):
    setup_logging(1)
    logging.getLogger("servogym.autotune._session").info("waiting for 3 trial(s)")
    assert "waiting for 3 trial(s)" in capsys.readouterr().err
    setup_logging(0)
    logging.getLogger("servogym.autotune._session").info("hidden")
    assert "hidden" not in capsys.readouterr().err
