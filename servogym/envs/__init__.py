"""Gymnasium environments: tuning (one parameter set per axis) and gain scheduling.

Every id is registered here, in one place, under the ``servogym/`` namespace, one per chip
family and plant family in the registries (:func:`servogym.chips._family.families`,
:data:`servogym.plants.PLANTS`) and version (:data:`VERSIONS`)::

    servogym/Tune-<Family>-<Plant>-v1       servogym/Schedule-<Family>-<Plant>-v1

``-v1`` ids scale their rewards by 0.01 (:data:`REWARD_SCALE_V1`); the ``-v0`` ids keep the
first release's behaviour (raw rewards). The gain-scheduling scenarios add
``servogym/Schedule-<Family>-<Scenario>-v1``.

``<Family>`` is the chip family's ``env_name`` (or its name in capitals: ``PMD``), the env
using the family's first model unless ``chip_model=`` names another
(``gymnasium.make("servogym/Tune-PMD-VerticalAxis-v1", chip_model="MC58000")``);
``<Plant>`` is the plant family in CamelCase (``VerticalAxis``). Importing this package
registers them, and so does ``import servogym`` (cheaply: string entry points).

Example:
    >>> import gymnasium as gym
    >>> import servogym
    >>> env = gym.make("servogym/Tune-PMD-VerticalAxis-v1")
"""

from __future__ import annotations

import textwrap

import gymnasium as gym

from servogym import _registration
from servogym.chips._family import ChipFamily, families
from servogym.envs._actions import (
    ACTION_TYPES,
    DEFAULT_RESIDUAL_SCALE,
    ActionMap,
    RawActions,
    ResidualActions,
    UnitActions,
)
from servogym.envs._common import DEFAULT_REWARD_SCALE, action_table, default_model
from servogym.envs._observe import MOVE_FEATURES, OBS_CLIP
from servogym.envs._scenarios import SCENARIOS, ScheduleScenario, get_scenario
from servogym.envs._schedule import (
    CONDITION_FEATURES,
    CYCLES,
    STATE_FEATURES,
    GainTable,
    PickAndPlace,
    ScheduleEnv,
)
from servogym.envs._schedule import observation_table as _schedule_obs_table
from servogym.envs._tune import IDENT_SCALE, TuneEnv
from servogym.envs._tune import observation_table as _tune_obs_table
from servogym.envs._vector import GroupedAsyncVectorEnv
from servogym.plants import MULTI_PLANTS, PLANTS

NAMESPACE = _registration.NAMESPACE
VERSION = _registration.VERSION
VERSIONS = _registration.VERSIONS
REWARD_SCALE_V1 = _registration.REWARD_SCALE_V1
id_version = _registration.id_version
plant_id_name = _registration.plant_id_name
ENTRY_POINTS = _registration.ENTRY_POINTS


def family_id_name(family: ChipFamily) -> str:
    """The chip family's part of an env id (``PMD``)."""
    return getattr(family, "env_name", None) or family.name.upper()


def env_id(kind: str, family: ChipFamily, plant: str, version: int = VERSION) -> str:
    """The registered id of an env kind (``"Tune"``, ``"Schedule"``) for a family and plant
    (``version``: the newest by default)."""
    return _registration.make_id(kind, family_id_name(family), plant, version)


def register_envs() -> list[str]:
    """Register every kind x chip family x plant family (idempotent); return the ids.

    ``import servogym`` has already registered the built-in ones
    (:mod:`servogym._registration`); this adds any family or plant registered since.
    """
    ids = [
        eid
        for family in families().values()
        for plant in PLANTS
        for eid in _registration.register(
            family.name, family_id_name(family), default_model(family), plant
        )
    ]
    ids += [
        eid
        for family in families().values()
        for plant in MULTI_PLANTS
        for eid in _registration.register_machine(
            family.name, family_id_name(family), default_model(family), plant
        )
    ]
    for s in SCENARIOS.values():
        fam = families()[s.family]
        ids += _registration.register_scenario(
            s.name, s.family, family_id_name(fam), s.chip_model, s.plant
        )
    return ids


def registered_ids() -> list[str]:
    """Every servogym id in Gymnasium's registry (what the tests iterate over)."""
    return sorted(i for i in gym.registry if i.startswith(NAMESPACE + "/"))


def _fill(doc: str, **tables: str) -> str:
    for name, table in tables.items():
        doc = doc.replace("{" + name + "}", textwrap.indent(table, "    ").lstrip())
    return doc


_PMD_DEFAULT = "MC2100"
TuneEnv.__doc__ = _fill(
    TuneEnv.__doc__, action_table=action_table(_PMD_DEFAULT), observation_table=_tune_obs_table()
)
ScheduleEnv.__doc__ = _fill(
    ScheduleEnv.__doc__,
    action_table=action_table(_PMD_DEFAULT),
    observation_table=_schedule_obs_table(),
)

IDS = register_envs()
"""Every id registered at import."""

__all__ = [
    "ACTION_TYPES",
    "CONDITION_FEATURES",
    "CYCLES",
    "DEFAULT_RESIDUAL_SCALE",
    "DEFAULT_REWARD_SCALE",
    "IDENT_SCALE",
    "IDS",
    "MOVE_FEATURES",
    "NAMESPACE",
    "OBS_CLIP",
    "REWARD_SCALE_V1",
    "SCENARIOS",
    "STATE_FEATURES",
    "VERSION",
    "VERSIONS",
    "ActionMap",
    "GainTable",
    "GroupedAsyncVectorEnv",
    "PickAndPlace",
    "RawActions",
    "ResidualActions",
    "ScheduleEnv",
    "ScheduleScenario",
    "TuneEnv",
    "UnitActions",
    "env_id",
    "family_id_name",
    "get_scenario",
    "id_version",
    "plant_id_name",
    "register_envs",
    "registered_ids",
]
