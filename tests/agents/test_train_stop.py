"""Training a user can watch and stop (issue 19): progress lines when stdout is not a
terminal, model.zip and config.json at every checkpoint and on SIGTERM, --resume."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest

ENV = "servogym/Tune-PMD-Rotary-v1"


ALGO_KWARGS = '{"n_steps": 16, "batch_size": 16, "n_epochs": 1}'


def _train(out, *extra):
    return [sys.executable, "-m", "servogym", "train", "--env", ENV, "--algo", "ppo",
            "--n-envs", "1", "--checkpoint-every", "16", "--seed", "3", "--out", str(out),
            "--algo-kwargs", ALGO_KWARGS, *extra]  # fmt: skip


@pytest.mark.slow
def test_sigterm_saves_the_model_and_resume_continues(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        _train(out, "--timesteps", "100000"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 600
    while not list((out / "checkpoints").glob("ppo_*_steps.zip")):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no checkpoint in 600 s"
        time.sleep(0.5)
    # a checkpoint is also a loadable model with its config
    assert (out / "model.zip").exists()
    assert json.loads((out / "config.json").read_text())["trained_timesteps"] >= 16
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 143, (stdout, stderr)
    assert "train: " in stderr and "steps/s" in stderr  # progress without a terminal
    assert "stopped by SIGTERM" in stderr and "--resume" in stderr
    config = json.loads((out / "config.json").read_text())
    assert config["stopped_by"] == "SIGTERM"
    trained = config["trained_timesteps"]
    assert trained >= 16

    from servogym.agents._train import load_model

    model = load_model(out / "model.zip")  # the weights load into the run's policy
    assert model.policy is not None

    goal = trained + 32
    done = subprocess.run(
        _train(out, "--timesteps", str(goal), "--resume"),
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert json.loads((out / "config.json").read_text())["trained_timesteps"] >= goal

    # a resume with other settings is refused in one line, nothing trained
    other = subprocess.run(
        _train(out, "--timesteps", str(goal + 64), "--resume", "--seed", "4"),
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert other.returncode == 2 and "--seed" in other.stderr, other.stderr


def test_sigint_and_sigterm_ask_the_loop_to_stop_and_a_second_one_stops_at_once():
    import os

    from servogym.agents._train import _Stop

    for sig, name in ((signal.SIGINT, "SIGINT"), (signal.SIGTERM, "SIGTERM")):
        old = signal.getsignal(sig)
        with _Stop() as stop:
            os.kill(os.getpid(), sig)
            time.sleep(0.05)
            assert stop.signal_name == name  # training goes on to its next step, then saves
            with pytest.raises(KeyboardInterrupt):
                os.kill(os.getpid(), sig)
                time.sleep(0.05)
        assert signal.getsignal(sig) is old  # the handlers are restored


def test_train_never_overwrites_a_trained_run_without_resume(tmp_path):
    from typer.testing import CliRunner

    from servogym.cli import app

    out = tmp_path / "run"
    out.mkdir()
    (out / "model.zip").write_bytes(b"a model")
    r = CliRunner().invoke(app, ["train", "--env", "servogym/Tune-PMD-Rotary-v1",
                                 "--timesteps", "10", "--out", str(out)])  # fmt: skip
    assert r.exit_code == 2, r.output
    assert "already holds a trained run (model.zip); pass --resume" in r.output
    assert (out / "model.zip").read_bytes() == b"a model"
