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
VERSION = 0

ENTRY_POINTS = {
    "Tune": "servogym.envs._tune:TuneEnv",
    "Schedule": "servogym.envs._schedule:ScheduleEnv",
}
"""Env kind -> entry point."""

BUILTIN_FAMILIES: dict[str, tuple[str, str]] = {
    "pmd": ("PMD", "MC2100"),
    "pmac": ("PMAC", "TurboPMAC2"),
    "parker6k": ("Parker6K", "6250"),
}
"""Chip family name -> (its part of an env id, the model an id uses by default)."""

BUILTIN_PLANTS: tuple[str, ...] = ("rotary", "two-mass", "vertical-axis", "arm")
"""Plant family names, in registry order."""


def plant_id_name(plant: str) -> str:
    """The plant family's part of an env id (``vertical-axis`` -> ``VerticalAxis``)."""
    return "".join(part.capitalize() for part in plant.replace("_", "-").split("-"))


def make_id(kind: str, family_id: str, plant: str) -> str:
    """``servogym/<kind>-<family_id>-<Plant>-v0``."""
    return f"{NAMESPACE}/{kind}-{family_id}-{plant_id_name(plant)}-v{VERSION}"


def register(family: str, family_id: str, default_model: str, plant: str) -> list[str]:
    """Register both kinds for one chip family and plant family (idempotent); return ids."""
    import gymnasium as gym

    ids = []
    for kind, entry_point in ENTRY_POINTS.items():
        eid = make_id(kind, family_id, plant)
        ids.append(eid)
        if eid not in gym.registry:
            gym.register(
                id=eid,
                entry_point=entry_point,
                kwargs={"chip_model": default_model, "plant": plant, "family": family},
                disable_env_checker=False,
            )
    return ids


def register_builtin() -> list[str]:
    """Register every built-in id; return them."""
    return [
        eid
        for family, (family_id, model) in BUILTIN_FAMILIES.items()
        for plant in BUILTIN_PLANTS
        for eid in register(family, family_id, model, plant)
    ]
