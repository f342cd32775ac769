"""Safe centres of the multi-axis Schedule ids' residual actions (servogym.envs._machine).

For each chip family's default model and multi-axis plant, one fixed register set per axis is
searched that runs the Schedule id's episodes well: the objective is the mean cost per move
of ``--episodes`` seeded episodes of ``--moves`` moves on the id with ``action_type="unit"``
(the action is the set itself). The search (Optuna TPE, multivariate, seed 0) starts from
the chip's defaults and every servobench-v1 best-known set of the family's default model
(its registers in the action), each put on every axis, then runs to ``--budget`` trials;
PMAC's notch registers are held off (:data:`HELD`). Prints, per id, the best set per
axis, its cost, and the defaults' cost; ``--out`` appends the results as JSON lines.

    python experiments/machine_schedule_centres.py --budget 60 --out \
        experiments/results/schedule/machine_centres.jsonl
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import optuna

import servogym.envs  # noqa: F401  (registers the ids)
from servogym import _registration

BENCH = Path(__file__).resolve().parents[1] / "servogym/autotune/bench/data/servobench-v1.json"


def bench_sets(model: str) -> list[dict[str, int]]:
    """servobench-v1's best-known sets of ``model`` (every plant family)."""
    instances = json.loads(BENCH.read_text())["instances"]
    prefix = f"servobench-v1/{model.lower()}/"
    return [dict(v["values"]) for k, v in instances.items() if k.startswith(prefix)]


def episode_cost(env, action: np.ndarray, seeds: list[int]) -> float:
    costs = []
    for seed in seeds:
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, done, _, info = env.step(action)
            costs.append(info["cost"])
    return float(np.mean(costs))


EXTRA = {"pmac": [dict(proportional_gain=60000, derivative_gain=3000, integral_gain=1000)]}
"""More starting sets: the PMAC gains of the loop's twin tests (tests/sim/test_runner.py)."""

HELD = ("notch_n1", "notch_n2", "notch_d1", "notch_d2")
"""Registers the search holds at the chip's defaults (PMAC's notch off): random notch
coefficients make an unstable filter, which every trial would spend its episodes on."""


def search(eid: str, budget: int, episodes: int, moves: int) -> dict:
    probe = gym.make(eid, action_type="unit").unwrapped
    space = probe.chip.parameter_space(probe.scenario.chip_model)
    held = {n: space[n].default for n in HELD if n in space}
    env = gym.make(eid, action_type="unit", n_moves=moves, fixed=held).unwrapped
    seeds = list(range(episodes))
    names = env.actions.names
    start = [env.actions.from_values({})]
    registers = {n.split(".", 1)[1] for n in names}
    for values in [*bench_sets(env.scenario.chip_model), *EXTRA.get(env.chip.name, [])]:
        start.append(env.actions.from_values({k: v for k, v in values.items() if k in registers}))
    study = optuna.create_study(
        sampler=optuna.samplers.TPESampler(seed=0, multivariate=True, n_startup_trials=10)
    )
    for a in start:
        study.enqueue_trial({n: float(x) for n, x in zip(names, a, strict=True)})

    def objective(trial: optuna.Trial) -> float:
        a = np.array([trial.suggest_float(n, -1.0, 1.0) for n in names], np.float32)
        return episode_cost(env, a, seeds)

    t = time.perf_counter()
    study.optimize(objective, n_trials=max(budget, len(start)))
    best = np.array([study.best_params[n] for n in names], np.float32)
    per_axis = env.actions.axis_values(best)
    return {
        "env_id": eid,
        "budget": len(study.trials),
        "episodes": episodes,
        "moves": moves,
        "best_cost": study.best_value,
        "defaults_cost": study.trials[0].value,
        "center": per_axis,
        "seconds": round(time.perf_counter() - t, 1),
    }


def main() -> None:
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=int, default=60)
    ap.add_argument("--episodes", type=int, default=2)
    ap.add_argument("--moves", type=int, default=4)
    ap.add_argument("--families", default=",".join(_registration.BUILTIN_FAMILIES))
    ap.add_argument("--plants", default=",".join(_registration.BUILTIN_MACHINE_PLANTS))
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    for family in args.families.split(","):
        family_id = _registration.BUILTIN_FAMILIES[family][0]
        for plant in args.plants.split(","):
            eid = _registration.make_id("Schedule", family_id, plant)
            row = search(eid, args.budget, args.episodes, args.moves)
            print(json.dumps(row), flush=True)
            if args.out:
                with args.out.open("a") as f:
                    f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
