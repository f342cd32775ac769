"""Agents: train SB3 policies on servogym envs and compare them with fixed-parameter baselines.

Importing this package does not import torch; the training functions do.
"""

from servogym.agents._baselines import NOMINAL_SETS, nominal_set
from servogym.agents._evaluate import (
    ConstantPolicy,
    EpisodeOutcome,
    GainTablePolicy,
    ModelPolicy,
    baseline_policies,
    paired_difference,
    reference_env,
    run_episodes,
    summarize,
)
from servogym.agents._train import (
    ALGOS,
    DEFAULT_REWARD_SCALE,
    load_model,
    load_policy,
    make_env,
    residual_env_kwargs,
    train,
)

__all__ = [
    "ALGOS",
    "DEFAULT_REWARD_SCALE",
    "NOMINAL_SETS",
    "ConstantPolicy",
    "EpisodeOutcome",
    "GainTablePolicy",
    "GroupedVecEnv",
    "ModelPolicy",
    "baseline_policies",
    "load_model",
    "load_policy",
    "make_env",
    "nominal_set",
    "paired_difference",
    "reference_env",
    "residual_env_kwargs",
    "run_episodes",
    "summarize",
    "train",
]


def __getattr__(name: str):
    if name == "GroupedVecEnv":  # imports stable_baselines3 (and torch) only when asked for
        from servogym.agents._vecenv import GroupedVecEnv

        return GroupedVecEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
