"""How far an untrained policy's exploration gets around a scenario's residual centre.

    nice -n 10 .venv/bin/python experiments/schedule_explore.py \\
        --env servogym/Schedule-PMD-VerticalCoarseLead-v1 --episodes 16 \\
        --centre nominal='{"kp": 6, "kd": 44, "ki": 75, "kaff": 427}'

For the id's own centre (``ScheduleScenario.center``) and every ``--centre NAME=JSON``:
``--episodes`` seeded episodes (seeds 0 ..) whose actions are drawn N(0, 1) and clipped to
the box, as an untrained PPO policy samples them (numpy generator seeded 0), and as many
episodes of the zero action (the centre itself, seeds 1000 ..). Prints one JSON line per
centre: mean episode length in moves, episodes that ran all their moves, mean cost per move
that did not diverge, and the zero action's mean cost and divergences.
"""

from __future__ import annotations

import argparse
import json

import gymnasium as gym
import numpy as np


def explore(env_id: str, centre: dict | None, n: int) -> dict:
    import servogym  # noqa: F401

    kwargs = {} if centre is None else {"center": centre}
    env = gym.make(env_id, **kwargs).unwrapped
    rng = np.random.default_rng(0)
    lengths, costs = [], []
    for seed in range(n):
        env.reset(seed=seed)
        k, done = 0, False
        while not done:
            a = np.clip(rng.normal(size=env.action_space.shape), -1, 1).astype(np.float32)
            _, _, done, _, info = env.step(a)
            k += 1
            if not info["diverged"]:
                costs.append(info["cost"])
        lengths.append(k)
    zero_costs, zero_diverged = [], 0
    for seed in range(n):
        env.reset(seed=1000 + seed)
        done = False
        while not done:
            _, _, done, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
            zero_diverged += bool(info["diverged"])
            zero_costs.append(info["cost"])
    return {
        "centre": env.actions.center_values,
        "mean_moves": float(np.mean(lengths)),
        "full_episodes": int(sum(n_k == env.n_moves for n_k in lengths)),
        "episodes": n,
        "explore_mean_cost": float(np.mean(costs)),
        "zero_mean_cost": float(np.mean(zero_costs)),
        "zero_diverged_moves": zero_diverged,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", default="servogym/Schedule-PMD-VerticalCoarseLead-v1")
    ap.add_argument("--episodes", type=int, default=16)
    ap.add_argument("--centre", action="append", default=[], help="NAME=JSON register values")
    args = ap.parse_args()
    centres: dict[str, dict | None] = {"the id's": None}
    for item in args.centre:
        name, _, text = item.partition("=")
        centres[name] = json.loads(text)
    for name, centre in centres.items():
        print(json.dumps({"name": name, **explore(args.env, centre, args.episodes)}), flush=True)


if __name__ == "__main__":
    main()
