"""Gymnasium registration of every env id at ``import servogym``, without the heavy imports.

``import servogym`` registers the ids of every built-in chip family and plant family with
string entry points, so numba, MuJoCo and the env classes load only when an env is made
(``gymnasium.make``, ``gym.register_envs(servogym)``, ``rl_zoo3 --gym-packages servogym``).
The tables here are the registries' names only; ``tests/envs/test_registration.py`` checks
them against the registries themselves (:func:`servogym.chips.families`,
:data:`servogym.plants.PLANTS`), and :func:`servogym.envs.register_envs` registers, from the
registries, any family or plant added after them.
"""

from __future__ import annotations

NAMESPACE = "servogym"
VERSION = 1
"""The newest version of the ids: what ``servogym train``'s examples, the RL Zoo files and the
docs use."""

REWARD_SCALE_V1 = 0.01
"""The ``reward_scale`` of the ``-v1`` ids (the env classes' own default, and the ``-v0``
ids', is 1.0: raw rewards)."""

VERSIONS: dict[int, dict[str, float]] = {
    0: {},
    1: {"reward_scale": REWARD_SCALE_V1},
    2: {"reward_scale": REWARD_SCALE_V1, "machine_centers": 2},
}
"""Version -> the keyword arguments its ids pass on top of the env classes' defaults. ``-v0``:
the envs as first released (rewards are minus the cost); ``-v1``: rewards times 0.01;
``-v2`` (the multi-axis plants' Schedule ids only): the residual action acts around the
centres that pass the multi-axis check at every point of the cycle
(``servogym.envs._machine.MACHINE_CENTERS_V2``). The Version History of ``TuneEnv`` and
``ScheduleEnv`` (docs/envs.md) says what each changed."""

PLANT_VERSIONS: tuple[int, ...] = (0, 1)
"""The versions the single-axis plants' ids (both kinds) exist in."""

SCENARIO_VERSIONS: tuple[int, ...] = (1,)
"""The versions the gain-scheduling scenario ids exist in (they were added with ``-v1``)."""

MACHINE_VERSIONS: tuple[int, ...] = (1,)
"""The versions the multi-axis plants' ids of both kinds exist in (they were added with
``-v1``)."""

MACHINE_SCHEDULE_VERSIONS: tuple[int, ...] = (1, 2)
"""The versions the multi-axis plants' ``Schedule`` ids exist in: :data:`MACHINE_VERSIONS`
and ``-v2``, whose safe centres pass the multi-axis check (a ``Tune`` id has no centre, so
it has no ``-v2``)."""

ENTRY_POINTS = {
    "Tune": "servogym._registration:make_tune_env",
    "Schedule": "servogym._registration:make_schedule_env",
}
"""Env kind -> entry point (a function that checks the keywords against the id, then builds
the env class of :data:`ENV_CLASSES`)."""

ENV_CLASSES = {
    "Tune": "servogym.envs._tune:TuneEnv",
    "Schedule": "servogym.envs._schedule:ScheduleEnv",
}
"""Env kind -> the env class its ids build."""

_ID_PARTS: dict[str, tuple[str, str, str]] = {}
"""Registered id -> (kind, chip family, plant family)."""

_SCENARIO_IDS: set[str] = set()
"""The registered ids of gain-scheduling scenarios (:data:`SCENARIOS`)."""


def _build(kind: str, env_id: str | None, kwargs: dict):
    """The env of ``kind``, after refusing keywords that contradict ``env_id``'s chip
    family or plant family (``gym.make("servogym/Tune-PMD-Rotary-v0", plant="arm")``)."""
    import importlib

    if env_id is not None and env_id in _ID_PARTS:
        _, family, plant = _ID_PARTS[env_id]
        scenario = kwargs.get("scenario")
        chip = getattr(scenario, "chip", None)
        given = (
            ("plant", kwargs.get("plant", plant), plant, "plant family"),
            ("family", kwargs.get("family", family), family, "chip family"),
            ("scenario.plant", getattr(scenario, "plant", plant), plant, "plant family"),
            ("scenario's chip family", getattr(chip, "name", family), family, "chip family"),
        )
        for key, value, want, what in given:
            if value == want:
                continue
            version = id_version(env_id)
            other = (
                _id_for(kind, family, value, version) if what == "plant family"
                else _id_for(kind, value, plant, version)
            )  # fmt: skip
            hint = f"; make {other} for that one" if other else ""
            raise ValueError(
                f"{key}={value!r} contradicts the env id {env_id}, whose {what} is {want!r}{hint}."
            )
    module, _, name = ENV_CLASSES[kind].partition(":")
    return getattr(importlib.import_module(module), name)(**kwargs)


def _id_for(kind: str, family: str, plant: str, version: int) -> str | None:
    return next(
        (i for i, parts in _ID_PARTS.items()
         if parts == (kind, family, plant) and i not in _SCENARIO_IDS
         and id_version(i) == version),
        None,
    )  # fmt: skip


def id_version(env_id: str) -> int:
    """The version of a servogym id (``servogym/Tune-PMD-Rotary-v1`` -> 1)."""
    return int(env_id.rsplit("-v", 1)[1])


def make_tune_env(env_id: str | None = None, **kwargs):
    """Gymnasium's entry point of the ``Tune`` ids (see :func:`_build`)."""
    return _build("Tune", env_id, kwargs)


def make_schedule_env(env_id: str | None = None, **kwargs):
    """Gymnasium's entry point of the ``Schedule`` ids (see :func:`_build`)."""
    return _build("Schedule", env_id, kwargs)


BUILTIN_FAMILIES: dict[str, tuple[str, str]] = {
    "pmd": ("PMD", "MC2100"),
    "pmac": ("PMAC", "TurboPMAC2"),
    "parker6k": ("Parker6K", "6250"),
}
"""Chip family name -> (its part of an env id, the model an id uses by default)."""

BUILTIN_PLANTS: tuple[str, ...] = ("rotary", "two-mass", "vertical-axis", "arm")
"""Plant family names, in registry order."""

BUILTIN_MACHINE_PLANTS: tuple[str, ...] = ("two-link-arm", "xy-stage")
"""Multi-axis plant family names, in registry order (their ids exist in
:data:`MACHINE_VERSIONS`)."""


def plant_id_name(plant: str) -> str:
    """The plant family's part of an env id (``vertical-axis`` -> ``VerticalAxis``)."""
    return "".join(part.capitalize() for part in plant.replace("_", "-").split("-"))


def make_id(kind: str, family_id: str, plant: str, version: int = VERSION) -> str:
    """``servogym/<kind>-<family_id>-<Plant>-v<version>``."""
    return f"{NAMESPACE}/{kind}-{family_id}-{plant_id_name(plant)}-v{version}"


def register(
    family: str,
    family_id: str,
    default_model: str,
    plant: str,
    versions: tuple[int, ...] = PLANT_VERSIONS,
    kinds: tuple[str, ...] = tuple(ENTRY_POINTS),
) -> list[str]:
    """Register ``kinds`` (default: both) for one chip family and plant family, in every
    version of ``versions`` (default: :data:`PLANT_VERSIONS`; idempotent); return the ids."""
    import gymnasium as gym

    ids = []
    for version in versions:
        defaults = VERSIONS[version]
        for kind in kinds:
            entry_point = ENTRY_POINTS[kind]
            eid = make_id(kind, family_id, plant, version)
            ids.append(eid)
            _ID_PARTS[eid] = (kind, family, plant)
            if eid not in gym.registry:
                gym.register(
                    id=eid,
                    entry_point=entry_point,
                    kwargs={
                        "env_id": eid,
                        "chip_model": default_model,
                        "plant": plant,
                        "family": family,
                        **defaults,
                    },
                    disable_env_checker=False,
                )
    return ids


def register_machine(family: str, family_id: str, default_model: str, plant: str) -> list[str]:
    """Register the ids of a multi-axis plant: both kinds in :data:`MACHINE_VERSIONS`, the
    ``Schedule`` ids also in the rest of :data:`MACHINE_SCHEDULE_VERSIONS` (idempotent);
    return the ids."""
    ids = register(family, family_id, default_model, plant, MACHINE_VERSIONS)
    later = tuple(v for v in MACHINE_SCHEDULE_VERSIONS if v not in MACHINE_VERSIONS)
    return ids + register(family, family_id, default_model, plant, later, ("Schedule",))


SCENARIOS: dict[str, tuple[str, str, str]] = {
    "ArmPayload": ("pmd", "MC2100", "arm"),
    "RotaryInertia": ("pmd", "MC2100", "rotary"),
    "VerticalCoarseLead": ("pmd", "MC2100", "vertical-axis"),
    "StoredSets": ("parker6k", "6250", "rotary"),
}
"""Gain-scheduling scenario name -> (chip family, chip model, plant family): the ids
``servogym/Schedule-<Family>-<Name>-v1`` (:data:`servogym.envs.SCENARIOS` holds the rest;
``tests/envs/test_registration.py`` checks the two agree)."""


def register_scenario(name: str, family: str, family_id: str, model: str, plant: str) -> list[str]:
    """Register the Schedule ids of one gain-scheduling scenario, in every version of
    :data:`SCENARIO_VERSIONS` (idempotent); return them."""
    import gymnasium as gym

    ids = []
    for version in SCENARIO_VERSIONS:
        eid = f"{NAMESPACE}/Schedule-{family_id}-{name}-v{version}"
        ids.append(eid)
        _ID_PARTS[eid] = ("Schedule", family, plant)
        _SCENARIO_IDS.add(eid)
        if eid not in gym.registry:
            gym.register(
                id=eid,
                entry_point=ENTRY_POINTS["Schedule"],
                kwargs={
                    "env_id": eid,
                    "chip_model": model,
                    "plant": plant,
                    "family": family,
                    "scenario_name": name,
                    **VERSIONS[version],
                },
                disable_env_checker=False,
            )
    return ids


def register_builtin() -> list[str]:
    """Register every built-in id; return them."""
    ids = [
        eid
        for family, (family_id, model) in BUILTIN_FAMILIES.items()
        for plant in BUILTIN_PLANTS
        for eid in register(family, family_id, model, plant)
    ]
    ids += [
        eid
        for family, (family_id, model) in BUILTIN_FAMILIES.items()
        for plant in BUILTIN_MACHINE_PLANTS
        for eid in register_machine(family, family_id, model, plant)
    ]
    for name, (family, model, plant) in SCENARIOS.items():
        ids += register_scenario(name, family, BUILTIN_FAMILIES[family][0], model, plant)
    return ids
