"""Training, saving, evaluating; the CLI commands; import weight."""

from __future__ import annotations

import json
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import typer
from typer.testing import CliRunner

import servogym.envs  # noqa: F401
from servogym.agents import (
    ConstantPolicy,
    baseline_policies,
    load_model,
    paired_difference,
    run_episodes,
    summarize,
    train,
)
from servogym.agents._cli import evaluate_command, train_command

TUNE = "servogym/Tune-PMD-Rotary-v0"
SCHEDULE = "servogym/Schedule-PMD-VerticalAxis-v0"


def _app() -> typer.Typer:
    app = typer.Typer(pretty_exceptions_enable=False)
    app.command("train")(train_command)
    app.command("evaluate")(evaluate_command)
    return app


def test_import_servogym_does_not_import_torch():
    code = (
        "import sys, servogym, servogym.envs, servogym.agents;"
        "sys.exit(1 if 'torch' in sys.modules or 'stable_baselines3' in sys.modules else 0)"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("algo", ["ppo", "sac", "td3"])
def test_train_saves_model_checkpoints_logs_and_config(tmp_path, algo):
    kw = {"n_steps": 32, "batch_size": 32} if algo == "ppo" else {"learning_starts": 16}
    path = train(
        SCHEDULE,
        algo,
        64,
        seed=0,
        out=tmp_path,
        n_envs=2,
        subprocess=False,
        algo_kwargs=kw,
        env_kwargs={"n_moves": 4},
        checkpoint_every=32,
        progress_bar=False,
    )
    assert path.exists() and (tmp_path / "checkpoints").is_dir()
    assert any((tmp_path / "checkpoints").iterdir())
    assert any((tmp_path / "tensorboard").iterdir())
    config = json.loads((tmp_path / "config.json").read_text())
    assert config["algo"] == algo and config["trained_timesteps"] >= 64
    model = load_model(path)
    env = gym.make(SCHEDULE, n_moves=4)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(action)


def test_unknown_algo_is_an_error(tmp_path):
    with pytest.raises(ValueError, match="algo must be one of ppo, sac, td3"):
        train(TUNE, "dqn", 10, out=tmp_path)


def test_baselines_are_deterministic_on_the_same_seeds():
    env = gym.make(TUNE)
    policies = baseline_policies(env, {"my set": {"kp": 500, "kd": 3000}})
    assert "chip defaults" in policies and "my set" in policies
    a = run_episodes(env, policies["my set"], range(5))
    b = run_episodes(env, policies["my set"], range(5))
    assert a == b
    d = run_episodes(env, policies["chip defaults"], range(5))
    diff = paired_difference(a, d)
    assert diff["mean"] == pytest.approx(summarize(a)["mean_return"] - summarize(d)["mean_return"])
    with pytest.raises(ValueError, match="same seeds"):
        paired_difference(a, d[::-1])


def test_constant_policy_of_the_defaults_gives_the_default_registers():
    env = gym.make(SCHEDULE).unwrapped
    env.reset(seed=0)
    policy = baseline_policies(env)["chip defaults"]
    *_, info = env.step(policy(np.zeros(1)))
    space = env.chip.parameter_space(env.scenario.chip_model)
    assert info["params"] == {n: space[n].default for n in env.actions.names}
    assert isinstance(policy, ConstantPolicy)


def test_cli_train_then_evaluate(tmp_path):
    runner = CliRunner()
    out = tmp_path / "run"
    res = runner.invoke(
        _app(),
        ["train", "--env", TUNE, "--algo", "ppo", "--timesteps", "32", "--seed", "1",
         "--out", str(out), "--n-envs", "1", "--algo-kwargs", '{"n_steps": 16, "batch_size": 16}'],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert (out / "model.zip").exists()
    fixed = tmp_path / "fixed.json"
    fixed.write_text(json.dumps({"kp": 400, "kd": 2000}))
    res = runner.invoke(
        _app(),
        ["evaluate", "--model", str(out / "model.zip"), "--episodes", "3", "--fixed", str(fixed),
         "--json"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    table = json.loads(res.output)
    assert table["env"] == TUNE
    assert {"policy", "chip defaults", "best fixed set"} <= set(table)
    assert all(np.isfinite(table[k]["mean_return"]) for k in ("policy", "chip defaults"))


def test_cli_rejects_a_mistyped_env_id_with_suggestions():
    res = CliRunner().invoke(_app(), ["evaluate", "--env", "servogym/Tune-PMD-Rotry-v0"])
    assert res.exit_code == 2
    assert "Did you mean" in res.output and "servogym/Tune-PMD-Rotary-v0" in res.output


@pytest.mark.parametrize("key", sorted(__import__("servogym.agents").agents.NOMINAL_SETS))
def test_hand_tuned_nominal_sets_beat_the_defaults_on_the_nominal_plant(key):
    from servogym.agents import NOMINAL_SETS
    from servogym.chips._family import families
    from servogym.envs._common import default_model
    from servogym.sim import Evaluator, Scenario

    family, plant = key
    sc = Scenario(default_model(families()[family]), plant)
    ev = Evaluator(sc)
    tuned = ev.evaluate(sc.params(NOMINAL_SETS[key])).cost
    assert tuned < 0.5 * ev.evaluate(sc.default_params()).cost


def test_residual_actions_act_around_a_fixed_set(tmp_path):
    from servogym.agents import ResidualAction, load_policy

    env = gym.make(SCHEDULE, n_moves=2)
    center = env.unwrapped.actions.from_values({"kp": 300, "kd": 1000})
    wrapped = ResidualAction(env, center, 0.3)
    np.testing.assert_allclose(wrapped.action(np.zeros_like(center)), center, atol=1e-6)
    assert (wrapped.action(np.full_like(center, 1.0)) <= 1.0).all()
    wrapped.reset(seed=0)
    *_, info = wrapped.step(np.zeros_like(center))
    assert info["params"]["kp"] == 300 and info["params"]["kd"] == 1000
    path = train(
        SCHEDULE, "sac", 16, out=tmp_path, n_envs=1, subprocess=False, progress_bar=False,
        env_kwargs={"n_moves": 2}, algo_kwargs={"learning_starts": 8},
        residual={"center": center, "scale": 0.3},
    )  # fmt: skip
    policy = load_policy(path)
    obs, _ = env.reset(seed=0)
    a = policy(obs)
    assert env.action_space.contains(a)
    assert np.abs(a - center).max() <= 0.3 + 1e-6
