"""`import servogym` registers every env id, cheaply, and docs/envs.md lists exactly those."""

from __future__ import annotations

import json
import pathlib
import re
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest

import servogym.envs as envs
from servogym import _registration
from servogym.chips._family import families
from servogym.envs._common import default_model
from servogym.plants import MULTI_PLANTS, PLANTS

DOCS = pathlib.Path(__file__).resolve().parents[2] / "docs" / "envs.md"


def test_the_import_time_tables_are_the_registries():
    assert {
        f.name: (envs.family_id_name(f), default_model(f)) for f in families().values()
    } == _registration.BUILTIN_FAMILIES
    assert tuple(PLANTS) == _registration.BUILTIN_PLANTS
    assert sorted(_registration.register_builtin()) == envs.registered_ids()


FRESH = """
import json, sys, time
t = time.perf_counter()
import servogym
elapsed = time.perf_counter() - t
import gymnasium as gym
heavy = sorted(m for m in ("numba", "mujoco", "torch", "optuna", "servogym.envs")
               if m in sys.modules)
ids = sorted(i for i in gym.registry if i.startswith("servogym/"))
gym.register_envs(servogym)
env = gym.make("servogym/Tune-PMD-VerticalAxis-v1")
obs, _ = env.reset(seed=0)
print(json.dumps({"ids": ids, "heavy": heavy, "shape": list(obs.shape), "s": elapsed}))
"""


def test_import_servogym_registers_every_id_without_loading_the_simulator():
    out = subprocess.run(
        [sys.executable, "-c", FRESH], capture_output=True, text=True, check=True, timeout=300
    )
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["ids"] == envs.registered_ids()
    n_versions = len(_registration.PLANT_VERSIONS)
    n_scenario_ids = len(envs.SCENARIOS) * len(_registration.SCENARIO_VERSIONS)
    n_machine_ids = (
        len(families())
        * len(MULTI_PLANTS)
        * (len(_registration.MACHINE_VERSIONS) + len(_registration.MACHINE_SCHEDULE_VERSIONS))
    )  # both kinds in MACHINE_VERSIONS, Schedule in MACHINE_SCHEDULE_VERSIONS
    assert len(got["ids"]) == (
        2 * len(families()) * len(PLANTS) * n_versions + n_scenario_ids + n_machine_ids
    )
    assert got["heavy"] == []  # no numba, MuJoCo, torch, Optuna until an env is made
    assert got["shape"] == [12]  # the Tune observation (docs/envs.md)
    assert got["s"] < 5.0


def test_docs_list_exactly_the_registered_ids():
    listed = re.findall(r"^- `(servogym/[^`]+)`$", DOCS.read_text(), flags=re.M)
    assert listed == envs.registered_ids()


EXPECTED_SCALE = {0: 1.0, 1: 0.01, 2: 0.01}
"""What each version's rewards are: -v0 raw (as first released), -v1 and -v2 times 0.01."""


def _first_step(eid: str, **kwargs):
    with warnings.catch_warnings():  # making a -v0 id warns that -v1 exists (Gymnasium)
        warnings.simplefilter("ignore", DeprecationWarning)
        env = gym.make(eid, **kwargs)
    env.reset(seed=0)
    env.action_space.seed(0)
    _, reward, *_, info = env.step(env.action_space.sample())
    return env.unwrapped, reward, info


@pytest.mark.parametrize("eid", envs.registered_ids())
def test_every_id_scales_its_rewards_as_its_version_says(eid):
    version = envs.id_version(eid)
    env, reward, info = _first_step(eid)
    assert env.reward_scale == EXPECTED_SCALE[version]
    assert reward == EXPECTED_SCALE[version] * info["raw_reward"]
    assert info["cost"] == -info["raw_reward"]


@pytest.mark.parametrize("eid", [i for i in envs.registered_ids() if i.endswith("-v2")])
def test_v2_and_v1_differ_only_in_the_residual_actions_centre(eid):
    v2, _, _ = _first_step(eid)
    v1, _, _ = _first_step(eid[: -len("v2")] + "v1")
    assert (v2.action_space, v2.observation_space) == (v1.action_space, v1.observation_space)
    assert v2.reward_scale == v1.reward_scale
    zero = np.zeros(v2.action_space.shape, np.float32)
    assert v2.actions.to_values(zero) != v1.actions.to_values(zero)
    like_v2, _, _ = _first_step(eid[: -len("v2")] + "v1", machine_centers=2)
    assert like_v2.actions.to_values(zero) == v2.actions.to_values(zero)


@pytest.mark.parametrize("eid", [i for i in envs.registered_ids() if i.endswith("-v0")])
def test_v0_and_v1_differ_only_in_the_reward_scale(eid):
    v0, r0, info0 = _first_step(eid)
    v1, r1, info1 = _first_step(eid[: -len("v0")] + "v1")
    assert (v0.action_space, v0.observation_space) == (v1.action_space, v1.observation_space)
    assert info0["raw_reward"] == info1["raw_reward"] == r0 and r1 == 0.01 * r0
    _, r0_scaled, _ = _first_step(eid, reward_scale=0.01)
    assert r0_scaled == r1


def test_the_scenario_ids_exist_from_v1_and_v0_of_them_is_refused():
    assert _registration.SCENARIO_VERSIONS == (1,)
    ids = envs.registered_ids()
    for name in envs.SCENARIOS:
        assert any(i.endswith(f"-{name}-v1") for i in ids)
        assert not any(i.endswith(f"-{name}-v0") for i in ids)
    with pytest.raises(gym.error.Error, match="v1"):
        gym.make("servogym/Schedule-PMD-RotaryInertia-v0")


def test_the_version_history_names_every_version():
    tune_versions = {*_registration.PLANT_VERSIONS, *_registration.MACHINE_VERSIONS}
    for cls, versions in ((envs.TuneEnv, tune_versions), (envs.ScheduleEnv, envs.VERSIONS)):
        doc = cls.__doc__
        assert "## Version History" in doc
        history = doc.split("## Version History")[1]
        for version in versions:
            assert f"* v{version}:" in history
        assert "0.01" in history.split("* v0:")[0]  # v1 says what it changed
    text = DOCS.read_text()
    assert "## Version history" in text and "v1" in text.split("## Version history")[1]
