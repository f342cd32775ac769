"""`servogym evaluate --model` never unpickles a model file: a malicious zip runs nothing."""

from __future__ import annotations

import base64
import json
import os
import pickle
import zipfile
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from servogym.cli import app

TUNE = "servogym/Tune-PMD-Rotary-v1"


class _Payload:
    """Unpickling it creates the marker file: proof that code from the file ran."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _evil_run(tmp_path: Path, policy_bytes: bytes, marker: Path) -> Path:
    run = tmp_path / "evil"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"env_id": TUNE, "algo": "ppo"}))
    serialized = base64.b64encode(pickle.dumps(_Payload(marker))).decode()
    data = {"policy_class": {":type:": "<class 'x'>", ":serialized:": serialized}}
    with zipfile.ZipFile(run / "model.zip", "w") as zf:
        zf.writestr("data", json.dumps(data))
        zf.writestr("policy.pth", policy_bytes)
        zf.writestr("_stable_baselines3_version", "2.0.0")
    return run / "model.zip"


def _torch_pickle(obj) -> bytes:
    import io

    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()


@pytest.mark.parametrize("form", ["torch-zip", "raw-pickle"])
def test_malicious_model_zip_runs_nothing(tmp_path, form):
    marker = tmp_path / "pwned"
    payload = _Payload(marker)
    blob = _torch_pickle(payload) if form == "torch-zip" else pickle.dumps(payload)
    assert not marker.exists()
    model = _evil_run(tmp_path, blob, marker)
    res = CliRunner().invoke(app, ["evaluate", "--model", str(model), "--episodes", "1"])
    assert res.exit_code == 2, res.output
    assert not marker.exists(), "code from the model file ran"
    assert "Traceback" not in res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: --model")
    assert "policy.pth holds more than weights" in lines[0]
    # Control: the same payload does run when unpickled the unsafe way.
    pickle.loads(pickle.dumps(payload))
    assert marker.exists()


def test_model_without_config_is_refused_unread(tmp_path):
    marker = tmp_path / "pwned"
    model = _evil_run(tmp_path, pickle.dumps(_Payload(marker)), marker)
    (model.parent / "config.json").unlink()
    res = CliRunner().invoke(app, ["evaluate", "--model", str(model), "--env", TUNE])
    assert res.exit_code == 2 and not marker.exists()
    assert "has no config.json next to it" in res.output and "Traceback" not in res.output


def test_weights_that_do_not_fit_the_policy_are_refused(tmp_path):
    marker = tmp_path / "never"
    model = _evil_run(tmp_path, _torch_pickle({"w": torch.zeros(3)}), marker)
    res = CliRunner().invoke(app, ["evaluate", "--model", str(model), "--episodes", "1"])
    assert res.exit_code == 2
    assert "do not fit the ppo policy" in res.output and "Traceback" not in res.output
