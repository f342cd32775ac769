"""`import servogym` registers every env id, cheaply, and docs/envs.md lists exactly those."""

from __future__ import annotations

import json
import pathlib
import re
import subprocess
import sys

import servogym.envs as envs
from servogym import _registration
from servogym.chips._family import families
from servogym.envs._common import default_model
from servogym.plants import PLANTS

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
env = gym.make("servogym/Tune-PMD-VerticalAxis-v0")
obs, _ = env.reset(seed=0)
print(json.dumps({"ids": ids, "heavy": heavy, "shape": list(obs.shape), "s": elapsed}))
"""


def test_import_servogym_registers_every_id_without_loading_the_simulator():
    out = subprocess.run(
        [sys.executable, "-c", FRESH], capture_output=True, text=True, check=True, timeout=300
    )
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["ids"] == envs.registered_ids()
    assert len(got["ids"]) == 2 * len(families()) * len(PLANTS) + len(envs.SCENARIOS)
    assert got["heavy"] == []  # no numba, MuJoCo, torch, Optuna until an env is made
    assert got["shape"] == [12]  # the Tune observation (docs/envs.md)
    assert got["s"] < 5.0


def test_docs_list_exactly_the_registered_ids():
    listed = re.findall(r"^- `(servogym/[^`]+)`$", DOCS.read_text(), flags=re.M)
    assert listed == envs.registered_ids()
