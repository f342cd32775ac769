"""The main job completes for every chip model on every plant (issue 11: the 6250 failed in
export after its study), and every model is found in a fresh process."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from typer.testing import CliRunner

from servogym._files import check_file_set
from servogym.autotune import TuneConfig, tune
from servogym.autotune._report import export_names
from servogym.chips import all_models, get_chip, read_params_file
from servogym.cli import app
from servogym.plants import PLANTS

from .helpers import SHORT_MOVES

MODELS = sorted(all_models())


def _check_outputs(out, model: str) -> None:
    family, _ = get_chip(model)
    manifest = check_file_set(out)  # every file there, every hash right
    summary = json.loads((out / "summary.json").read_text())
    best = read_params_file(out / "best_params.json").params
    assert best.model == model and manifest["trial"] == summary["best_trial"]
    for fmt, name in export_names(family, model).items():
        assert name in manifest["files"], fmt
        assert read_params_file(out / name).params == best, fmt


@pytest.mark.parametrize("model", MODELS)
def test_main_job_completes_for_every_chip_model(tmp_path, model):
    # --force: at budget 2 the set may fail the check (issue 13), and this test is about the
    # job reaching and writing every export the model takes; the check still runs.
    config = TuneConfig(
        chip=model, plant="rotary", out=tmp_path, budget=2, tuner="random", workers=1,
        moves=SHORT_MOVES["rotary"], batch_size=2, check_candidates=1, force=True,
    )  # fmt: skip
    _, summary = tune(config)
    assert summary["check"]["cases"] and summary["hardware_files_withheld"] == []
    _check_outputs(tmp_path, model)


@pytest.mark.slow
@pytest.mark.parametrize("plant", sorted(PLANTS))
@pytest.mark.parametrize("model", MODELS)
def test_servogym_tune_completes_for_every_chip_model_on_every_plant(tmp_path, model, plant):
    out = tmp_path / "run"
    args = ["tune", "--chip", model, "--plant", plant, "--budget", "3", "--out", str(out),
            "--tuner", "random", "--workers", "1", "--check-candidates", "1",
            "--force"]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    _check_outputs(out, model)


def test_every_chip_model_is_found_in_a_fresh_process():
    code = (
        "import sys; from servogym.chips import get_chip\n"
        "for name in sys.argv[1:]:\n"
        "    assert get_chip(name)[1] == name and get_chip(name.lower())[1] == name, name\n"
    )
    subprocess.run([sys.executable, "-c", code, *MODELS], check=True)
