"""The envs' ``plant_range=``: draws inside it, refusals in one line."""

import gymnasium as gym
import pytest

import servogym  # noqa: F401  (registers the envs)
from servogym.plants import MotorFeasibilityError, PlantParameterError


def test_tune_env_draws_inside_the_range():
    env = gym.make("servogym/Tune-PMD-Arm-v1", plant_range={"payload_kg": (1.0, 1.5)})
    for seed in range(4):
        env.reset(seed=seed)
        assert 1.0 <= env.unwrapped.evaluator.plant.values["payload_kg"] <= 1.5
    env.close()


def test_schedule_env_part_comes_from_the_range():
    env = gym.make(
        "servogym/Schedule-PMD-Rotary-v1", plant_range={"load_inertia_kgm2": (1e-4, 2e-4)}
    )
    assert env.unwrapped._part == (1e-4, 2e-4)
    env.close()


def test_schedule_env_default_part_is_movable():
    env = gym.make("servogym/Schedule-PMD-Arm-v1")
    assert env.unwrapped._part[1] == 2.5  # the default sampling range, not the legal 5 kg
    env.close()


@pytest.mark.parametrize(
    ("plant_range", "error", "match"),
    [
        ({"payload": (1, 2)}, PlantParameterError, r"plant_range: .*Did you mean payload_kg"),
        ({"payload_kg": (2, 1)}, PlantParameterError, r"payload_kg=2:1 must have low <= high"),
        ({"payload_kg": (1, 9)}, PlantParameterError, r"0\.05 <= payload_kg <= 5"),
        ({"payload_kg": 3}, PlantParameterError, r"must be a pair \(low, high\)"),
        ({"payload_kg": (1, 4.6)}, MotorFeasibilityError, r"payload_kg=4\.6 .*needs .*N\*m"),
    ],
)
def test_bad_ranges_are_refused_in_one_line(plant_range, error, match):
    with pytest.raises(error, match=match) as info:
        gym.make("servogym/Tune-PMD-Arm-v1", plant_range=plant_range)
    assert "\n" not in str(info.value)
