"""Running policies and baselines on the same seeded episodes."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

Policy = Callable[[np.ndarray], Any]
"""A policy: observation in, action out."""


@dataclasses.dataclass(frozen=True)
class EpisodeOutcome:
    """One episode of a policy.

    Attributes:
        seed: The seed given to ``reset``.
        episode_return: Sum of the unscaled rewards (minus the summed costs:
            ``info["raw_reward"]``, whatever the env's ``reward_scale``).
        n_steps: Steps taken.
        diverged: Whether a step diverged.
        mean_cost: Mean per-step cost (``info["cost"]``).
    """

    seed: int
    episode_return: float
    n_steps: int
    diverged: bool
    mean_cost: float


class ConstantPolicy:
    """The same action every step (a fixed parameter set)."""

    def __init__(self, action: Any) -> None:
        self.action = np.asarray(action)

    def __call__(self, obs: np.ndarray) -> Any:
        return self.action.copy()


class GainTablePolicy:
    """An industrial gain table: register sets tuned at K operating points of the scheduled
    parameter; before each move the set of the point nearest (in log scale) to the load the
    observation reports (:meth:`servogym.envs.ScheduleEnv.observed_load`), as a controller
    with stored gain sets chooses one per move. Acts in ``env``'s action space (the unit box
    of registers, or any action map with ``from_values``).

    Args:
        env: The env the table runs on (a Schedule env observing the condition).
        table: ``(operating point, register values)`` pairs, K >= 1, points > 0.
    """

    def __init__(self, env: Any, table: Iterable[tuple[float, Mapping[str, int]]]) -> None:
        from servogym.envs import GainTable

        self.env = env.unwrapped
        self.table = GainTable(table)
        self.actions = [self.env.actions.from_values(v) for _, v in self.table.rows]
        self.env.observed_load(np.zeros(self.env.observation_space.shape))  # condition=True?

    def __call__(self, obs: np.ndarray) -> Any:
        return self.actions[self.table.index(self.env.observed_load(obs))].copy()


def reference_env(env: Any) -> Any:
    """A twin of a made env whose loop integrates on the fine reference (RK4 with
    :data:`servogym.sim.REFERENCE_SUBSTEPS` substeps per servo period; docs/simulation.md):
    the same id and keyword arguments, so a seed gives the same plant, part and moves. What
    a result is re-checked on before it is reported."""
    import dataclasses

    import gymnasium as gym

    from servogym.sim import REFERENCE_SUBSTEPS

    spec = env.spec
    if spec is None:
        raise ValueError("reference_env needs an env made by gymnasium.make (it has no spec)")
    kwargs = dict(spec.kwargs)
    u = env.unwrapped
    for name in ("plant_range", "moves"):  # part of the scenario now
        kwargs.pop(name, None)
    sc = dataclasses.replace(u.scenario, substeps=REFERENCE_SUBSTEPS)
    return gym.make(spec.id, **{**kwargs, "scenario": sc})


class ModelPolicy:
    """An SB3 model's deterministic action, in the action space of the env it trained on
    (a run that acted around a set ran the env's own residual action:
    ``servogym.agents._train.run_env_kwargs`` rebuilds that env)."""

    def __init__(self, model: Any) -> None:
        self.model = model

    def __call__(self, obs: np.ndarray) -> Any:
        action, _ = self.model.predict(obs, deterministic=True)
        return action


def run_episodes(
    env: Any, policy: Policy, seeds: Iterable[int], on_episode: Callable[[], Any] | None = None
) -> list[EpisodeOutcome]:
    """Run one episode per seed (``env.reset(seed=s)``) and collect the outcomes.

    ``on_episode`` is called after each episode (the CLI's progress bar).
    """
    out = []
    for seed in seeds:
        obs, _ = env.reset(seed=int(seed))
        total, n, diverged, costs = 0.0, 0, False, []
        done = False
        while not done:
            obs, reward, terminated, truncated, info = env.step(policy(obs))
            total += float(info.get("raw_reward", reward))
            n += 1
            diverged |= bool(info.get("diverged", False))
            costs.append(float(info.get("cost", -reward)))
            done = terminated or truncated
        out.append(EpisodeOutcome(int(seed), total, n, diverged, float(np.mean(costs))))
        if on_episode is not None:
            on_episode()
    return out


def summarize(outcomes: list[EpisodeOutcome]) -> dict[str, float]:
    """Mean, standard error, median and worst return, divergence count, mean step cost."""
    r = np.array([o.episode_return for o in outcomes])
    return {
        "n_episodes": len(outcomes),
        "mean_return": float(r.mean()),
        "sem_return": float(r.std(ddof=1) / np.sqrt(len(r))) if len(r) > 1 else 0.0,
        "median_return": float(np.median(r)),
        "worst_return": float(r.min()),
        "n_diverged": int(sum(o.diverged for o in outcomes)),
        "mean_step_cost": float(np.mean([o.mean_cost for o in outcomes])),
    }


def paired_difference(a: list[EpisodeOutcome], b: list[EpisodeOutcome]) -> dict[str, float]:
    """Return of ``a`` minus that of ``b`` on the same seeds: mean, standard error, wins."""
    if [o.seed for o in a] != [o.seed for o in b]:
        raise ValueError("paired_difference needs outcomes on the same seeds, in order")
    d = np.array([x.episode_return - y.episode_return for x, y in zip(a, b, strict=True)])
    return {
        "mean": float(d.mean()),
        "sem": float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0,
        "a_better": int((d > 0).sum()),
        "b_better": int((d < 0).sum()),
    }


def baseline_policies(
    env: Any, extra: Mapping[str, Mapping[str, int]] | None = None
) -> dict[str, ConstantPolicy]:
    """Constant-parameter baselines for an env: the chip's defaults, the hand-tuned nominal
    set of the chip family and plant (when :data:`~servogym.agents.NOMINAL_SETS` has one),
    and any ``extra`` named register sets (e.g. the tuner's best fixed set)."""
    from servogym.agents._baselines import nominal_set

    u = env.unwrapped
    actions = u.actions
    out = {"chip defaults": ConstantPolicy(actions.from_values({}))}
    nominal = nominal_set(u.chip.name, u.scenario.plant)
    if nominal is not None:
        out["hand-tuned nominal"] = ConstantPolicy(actions.from_values(nominal))
    for name, values in (extra or {}).items():
        out[name] = ConstantPolicy(actions.from_values(values))
    return out
