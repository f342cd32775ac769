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

TUNE = "servogym/Tune-PMD-Rotary-v1"
SCHEDULE = "servogym/Schedule-PMD-VerticalAxis-v1"


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
    res = CliRunner().invoke(_app(), ["evaluate", "--env", "servogym/Tune-PMD-Rotry-v1"])
    assert res.exit_code == 2
    assert "Did you mean" in res.output and "servogym/Tune-PMD-Rotary-v1" in res.output


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


def test_train_residual_is_the_envs_own_residual_action(tmp_path):
    from servogym.agents import load_policy, residual_env_kwargs
    from servogym.agents._train import run_env_kwargs
    from servogym.envs import ResidualActions

    values = {"kp": 300, "kd": 1000}
    kw = residual_env_kwargs(SCHEDULE, {"n_moves": 2}, {"center": values, "scale": 0.3})
    assert kw == {"n_moves": 2, "action_type": "residual", "center": values,
                  "residual_scale": 0.3}  # fmt: skip
    env = gym.make(SCHEDULE, **kw)
    assert isinstance(env.unwrapped.actions, ResidualActions)
    env.reset(seed=0)
    *_, info = env.step(np.zeros(env.action_space.shape, np.float32))
    assert info["params"]["kp"] == 300 and info["params"]["kd"] == 1000
    path = train(
        SCHEDULE, "sac", 16, out=tmp_path, n_envs=1, subprocess=False, progress_bar=False,
        env_kwargs={"n_moves": 2}, algo_kwargs={"learning_starts": 8},
        residual={"center": values, "scale": 0.3},
    )  # fmt: skip
    config = json.loads((tmp_path / "config.json").read_text())
    assert config["residual"] == {"center": values, "scale": 0.3}
    assert config["env_kwargs"] == {"n_moves": 2}  # what --resume compares
    policy = load_policy(path)
    run_env = gym.make(SCHEDULE, **run_env_kwargs(config)).unwrapped
    obs, _ = run_env.reset(seed=0)
    a = policy(obs)
    assert run_env.action_space.contains(a)
    kp = run_env.actions.specs[run_env.actions.names.index("kp")]
    got = run_env.actions.to_values(a)["kp"]  # one mapping: within the reach of the centre
    assert abs(kp.to_unit(got) - kp.to_unit(300)) <= 0.3 + 1e-3


def test_a_run_folder_with_a_unit_form_centre_rebuilds_the_same_residual_env():
    from servogym.agents import residual_env_kwargs

    plain = gym.make(SCHEDULE).unwrapped
    unit_centre = plain.actions.from_values({"kp": 300, "kd": 1000}).tolist()
    kw = residual_env_kwargs(SCHEDULE, {}, {"center": unit_centre, "scale": 0.3})
    defaults = plain.actions.to_values(np.asarray(unit_centre))
    assert kw["center"] == {n: defaults[n] for n in plain.actions.names}
    assert kw["center"]["kp"] == 300 and kw["residual_scale"] == 0.3


def test_train_residual_on_an_env_that_acts_around_a_set_already_is_refused(tmp_path):
    from servogym.agents import residual_env_kwargs

    residual = {"center": {"kp": 30}, "scale": 0.2}
    for eid, kw in (("servogym/Schedule-PMD-RotaryInertia-v1", {}),
                    (SCHEDULE, {"action_type": "residual"})):  # fmt: skip
        with pytest.raises(ValueError, match=r"already acts around a safe set .*would stack"):
            train(eid, "ppo", 16, out=tmp_path, n_envs=1, subprocess=False,
                  progress_bar=False, env_kwargs=kw, residual=residual)  # fmt: skip
    assert not any(tmp_path.iterdir())  # refused before anything was written
    with pytest.raises(ValueError, match=r"unit box of registers .*MultiDiscrete"):
        residual_env_kwargs(SCHEDULE, {"action_type": "raw"}, residual)


@pytest.mark.parametrize("eid", ["servogym/Tune-PMD-Rotary-v0", "servogym/Tune-PMD-Rotary-v1"])
def test_train_scales_the_rewards_once_on_either_version(eid, tmp_path, monkeypatch):
    import warnings

    from stable_baselines3.common.monitor import Monitor

    from servogym.agents import _train

    made = []
    make = _train._EnvFactory.__call__
    monkeypatch.setattr(_train._EnvFactory, "__call__", lambda self: made.append(make(self))
                        or made[-1])  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # -v0: Gymnasium says -v1 exists
        train(eid, "ppo", 16, out=tmp_path, n_envs=1, subprocess=False, progress_bar=False,
              algo_kwargs={"n_steps": 16, "batch_size": 16})  # fmt: skip
    (env,) = made
    assert isinstance(env, Monitor) and env.unwrapped.reward_scale == 0.01
    env.reset(seed=0)
    _, r, *_, info = env.step(env.action_space.sample())
    assert r == 0.01 * info["raw_reward"]  # the env's scale, nothing on top
    assert json.loads((tmp_path / "config.json").read_text())["reward_scale"] == 0.01


def test_evaluate_runs_the_baselines_with_their_own_registers_on_a_residual_id():
    eid = "servogym/Schedule-PMD-RotaryInertia-v1"
    res = CliRunner().invoke(
        _app(), ["evaluate", "--env", eid, "--episodes", "2", "--env-kwargs",
                 '{"n_moves": 2}', "--json"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    got = json.loads(res.output)["chip defaults"]
    unit = gym.make(eid, n_moves=2, action_type="unit")
    want = summarize(run_episodes(unit, ConstantPolicy(unit.unwrapped.actions.from_values({})),
                                  range(100_000, 100_002)))  # fmt: skip
    assert got["mean_return"] == want["mean_return"]
    # the residual box cannot reach the defaults: through it they would be another set
    residual = gym.make(eid).unwrapped.actions
    assert residual.to_values(residual.from_values({})) != unit.unwrapped.actions.to_values(
        unit.unwrapped.actions.from_values({})
    )


def test_cli_train_with_grouped_workers_gives_the_same_model(tmp_path):
    """--workers steps the --n-envs envs in fewer processes (GroupedVecEnv): the envs give
    the same steps, so PPO learns the same weights as with one process per env."""
    runner = CliRunner()
    base = ["train", "--env", SCHEDULE, "--algo", "ppo", "--timesteps", "32", "--seed", "3",
            "--n-envs", "4", "--algo-kwargs", '{"n_steps": 8, "batch_size": 16}']  # fmt: skip
    for name, extra in (("own", []), ("grouped", ["--workers", "2"])):
        res = runner.invoke(_app(), [*base, "--out", str(tmp_path / name), *extra])
        assert res.exit_code == 0, res.output
    own, grouped = (load_model(tmp_path / n / "model.zip") for n in ("own", "grouped"))
    a, b = own.policy.state_dict(), grouped.policy.state_dict()
    assert a.keys() == b.keys()
    for key in a:
        assert (a[key] == b[key]).all(), key
    res = runner.invoke(_app(), [*base, "--out", str(tmp_path / "bad"), "--workers", "5"])
    assert res.exit_code == 2
    assert "--workers must satisfy 1 <= --workers <= 4; got --workers 5" in res.output
