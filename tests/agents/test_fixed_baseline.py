"""A 'best fixed set' baseline is the set it names: never silently the chip defaults."""

import json

import gymnasium as gym
import pytest
from typer.testing import CliRunner

import servogym.envs  # noqa: F401
from servogym.chips import ParameterError
from servogym.chips.pmd import PMDParams, to_json
from servogym.cli import app

ENV = "servogym/Schedule-PMD-VerticalAxis-v1"
TUNED = dict(kp=60, kd=600, ki=20, kout=6000, derivative_time=1, bias=1200)


def evaluate(*args):
    result = CliRunner().invoke(app, ["evaluate", "--env", ENV, "--episodes", "2", "--json", *args])
    return result


def test_a_servogym_parameter_file_is_used_as_written(tmp_path):
    path = tmp_path / "best.json"
    path.write_text(to_json(PMDParams(model="MC2100", **TUNED)))
    result = evaluate("--fixed", str(path))
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    assert out["best fixed set"]["mean_return"] != out["chip defaults"]["mean_return"]
    flat = tmp_path / "flat.json"
    flat.write_text(json.dumps(TUNED))
    same = json.loads(evaluate("--fixed", str(flat)).output)
    assert same["best fixed set"] == out["best fixed set"]


def test_a_file_for_another_chip_model_is_refused(tmp_path):
    path = tmp_path / "best.json"
    path.write_text(to_json(PMDParams(model="MC58000", **TUNED)))
    result = evaluate("--fixed", str(path))
    assert result.exit_code != 0 and "MC58000 parameter set; the env runs MC2100" in result.output


def test_unknown_or_unused_registers_are_not_dropped():
    actions = gym.make(ENV).unwrapped.actions
    with pytest.raises(ParameterError, match="Did you mean kp"):
        actions.from_values({"kpp": 5})
    with pytest.raises(ValueError, match="motor_limit=1000, a register this env's action"):
        actions.from_values({"motor_limit": 1000})
    actions.from_values({"motor_limit": 32767, **TUNED})  # the value the env uses: fine
