"""Gain-scheduling policies against the baselines engineers use, per scenario (issue 21).

    .venv/bin/python experiments/schedule_oracle.py --scenarios RotaryInertia --points 5 \\
        --budget 150 --robust 4 --tuner safe --label full          # the baselines first
    .venv/bin/python experiments/schedule_policies.py --scenarios RotaryInertia --minutes 60

For each scenario of ``servogym.envs.SCENARIOS`` (``--scenarios`` picks some; ``TwoLinkArm``,
the machine scenario of ``schedule_oracle.MACHINE_SCENARIOS``, by name, with ``--center
best-fixed`` because ``center_table`` is single-axis only, and ``--oracle-label pooled``
because no single run of it gave a set that passes the check at every payload):

1. **Baselines** from the oracle study (``experiments/schedule_oracle.py``, its ``--label``
   and ``--budget``), each from the sets that passed ``servogym check`` (an engineer stores
   no other): the best fixed set (the lowest mean cost over the operating points, robust set
   or any point's set), the robust set, and the **gain table** (the points' sets; before
   each move the set of the point nearest, in log scale, to the load the observation
   reports: ``servogym.agents.GainTablePolicy``). The **oracle** cost is the
   study's: each point's own set at that point (``oracle_basis`` says so).
2. **Policy**: ``servogym.agents.train`` (SB3; hyperparameters from
   ``servogym/agents/hyperparams/<algo>.yml``, 2 envs in subprocesses) for at most
   ``--minutes`` of wall time on the scenario's registered id; on the Box ids the policy
   refines the gain table (``center_table``: its zero action runs the table's set for the
   coming move's load, its action reaches ``--residual-scale`` around it; ``--center
   best-fixed``: around the best fixed set), the 6250's picks one of its five stored sets.
   Resumable: a run folder that has trained its minutes is not trained again.
3. **Evaluation**: every policy on the same ``--episodes`` held-out seeds (from
   ``--eval-seed``, far from the training seeds), on the default integration and again on the
   **reference integration** (RK4, 32 substeps: ``servogym.agents.reference_env``; the policy
   acts on what the reference loop observes). An episode's cost is minus its raw return per
   move (``-sum(raw_reward) / n_moves``: a divergence's penalty counts). Every register set a
   policy emits is validated by the chip (``Scenario.params``); the refusals are counted.
   Blocks of episodes are stored in ``--episodes-out`` (resumable).
4. **Summary** (``--out``, ``experiments/results/schedule/summary.json``): per scenario the
   mean costs on the reference integration (``policy_mean_cost``, ``best_fixed_mean_cost``,
   ``gain_table_mean_cost``, ``oracle_mean_cost``), their bootstrap 95 % intervals, the
   paired ratios policy / best fixed and policy / gain table with intervals, the same on the
   default integration, divergences, chip refusals and the command.

The goal (issue 21): on at least one scenario, a policy mean cost >= 30 % below the best
fixed set's and below the gain table's.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).parent
RESULTS = HERE / "results" / "schedule"
ROOT = HERE.parent
EVAL_SEED = 1_000_000
"""First held-out seed: training resets its 2 envs from seeds 0 and 1 (then their own
generators), the oracle script's episodes use 100_000 onwards."""


def _parse(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", default=None, help="comma-separated names (default: all)")
    ap.add_argument("--algo", default=None, help="sac, ppo or td3 (default: sac; the 6250: ppo)")
    ap.add_argument("--minutes", type=float, default=60.0, help="wall time of training (<= 60)")
    ap.add_argument("--timesteps", type=int, default=200_000, help="training steps at most")
    ap.add_argument("--seed", type=int, default=0, help="the agent's and training envs' seed")
    ap.add_argument(
        "--center", choices=("table", "best-fixed"), default="table",
        help="what the policy's zero action runs: the gain table's set for the load, or the "
        "best fixed set",
    )  # fmt: skip
    ap.add_argument("--residual-scale", type=float, default=0.25, help="the residual's reach")
    ap.add_argument("--episodes", type=int, default=100, help="held-out episodes per policy")
    ap.add_argument("--eval-seed", type=int, default=EVAL_SEED, help="first held-out seed")
    ap.add_argument("--integrations", default="default,reference")
    ap.add_argument("--oracle-label", default="full")
    ap.add_argument("--oracle-budget", type=int, default=150)
    ap.add_argument("--workers", type=int, default=2, help="evaluation processes")
    ap.add_argument("--skip-train", action="store_true", help="evaluate the baselines only")
    ap.add_argument("--runs", type=Path, default=RESULTS / "policies", help="run folders")
    ap.add_argument("--oracle", type=Path, default=RESULTS / "oracle.jsonl")
    ap.add_argument("--episodes-out", type=Path, default=RESULTS / "episodes.jsonl")
    ap.add_argument("--out", type=Path, default=RESULTS / "summary.json")
    ap.add_argument("--docs", type=Path, default=ROOT / "docs" / "envs.md",
                    help="the page whose table of the summary is written again (only "
                    "when --out is the committed summary, or with --table-only)")  # fmt: skip
    ap.add_argument("--table-only", action="store_true",
                    help="write --out's table into --docs, nothing else")  # fmt: skip
    args = ap.parse_args(argv)
    if not 0 < args.residual_scale <= 2:
        raise SystemExit(f"--residual-scale must be in (0, 2]; got {args.residual_scale}.")
    if not 0 < args.minutes <= 60:
        raise SystemExit(f"--minutes must be in (0, 60]; got --minutes {args.minutes}.")
    for name in ("episodes", "timesteps", "workers", "oracle_budget"):
        if getattr(args, name) < 1:
            raise SystemExit(f"--{name.replace('_', '-')} must be >= 1.")
    bad = set(args.integrations.split(",")) - {"default", "reference"}
    if bad:
        raise SystemExit(f"--integrations: unknown {sorted(bad)}; give default,reference.")
    return args


# -- the baselines (from the oracle study) ------------------------------------------------


def baselines(s: Any, oracle_path: Path, label: str, budget: int) -> dict[str, Any]:
    """The oracle study's sets of scenario ``s``: best fixed, robust, the gain table, the
    oracle's mean cost over the points. The best fixed set is ``schedule_oracle.summarize``'s
    (only sets that passed the check); the gain table's rows are the points' sets that passed
    it (all, flagged, when none did). Raises ``SystemExit`` naming the command when the study
    is not there."""
    sys.path.insert(0, str(HERE))
    from schedule_oracle import summarize

    if label == POOLED:
        return pooled_baselines(s, oracle_path)
    records = []
    if oracle_path.exists():
        for line in oracle_path.read_text().splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if (rec.get("kind") == "set" and rec["scenario"] == s.name
                    and rec["label"] == label and rec["budget"] == budget):  # fmt: skip
                records.append(rec)
    by_k: dict[int, dict[str, dict[str, Any]]] = {}
    for rec in records:
        by_k.setdefault(int(rec["points"]), {})[str(rec["point"])] = rec
    for n in sorted(by_k, reverse=True):  # the largest finished study
        by = by_k[n]
        if all(str(i) in by for i in range(n)):
            points = [float(by[str(i)]["value"]) for i in range(n)]
            summary = summarize(records, s, points, label, budget)
            if summary is not None:
                break
    else:
        raise SystemExit(
            f"no finished oracle study of {s.name} (label {label!r}, budget {budget}) in "
            f"{oracle_path}; run: .venv/bin/python experiments/schedule_oracle.py --scenarios "
            f"{s.name} --budget {budget} --label {label} --tuner safe"
        )
    best = summary["best_fixed"]
    rows = [i for i in range(n) if by[str(i)]["check_passed"]] or list(range(n))
    return {
        "points": points,
        "table": [(points[i], by[str(i)]["values"]) for i in rows],
        "table_points": [points[i] for i in rows],
        "table_checked": all(by[str(i)]["check_passed"] for i in rows),
        "best_fixed_checked": summary["best_fixed_checked"],
        "best_fixed": best,
        "best_fixed_values": by[best]["values"],
        "robust_values": by["robust"]["values"],
        "oracle_costs": summary["oracle_costs"],
        "oracle_mean_cost": summary["oracle_mean_cost"],
        "best_fixed_point_mean_cost": summary["best_fixed_mean_cost"],
        "oracle_gap": summary["oracle_gap"],
        "checks_passed": {m: bool(v) for m, v in summary["checks_passed"].items()},
    }


POOLED = "pooled"
"""``--oracle-label pooled``: the baselines of ``schedule_oracle.py --pooled`` (every checked
set of every run, counted at the points where it passed the check; ``--oracle-budget`` is not
used). The machine scenario's (``TwoLinkArm``) baselines: no single run gave a set that passes
at every payload."""


def pooled_baselines(s: Any, oracle_path: Path, n_points: int = 3) -> dict[str, Any]:
    """:func:`baselines` from :func:`schedule_oracle.summarize_pooled`: the best fixed set is
    the cheapest of the sets checked at every point, the gain table's rows are each point's
    cheapest set checked there (the pooled oracle's sets). No robust set of its own
    (``robust_values`` is ``None``)."""
    from schedule_oracle import _done, checked_at_points, pooled_sets, summarize_pooled

    done = _done(oracle_path) if oracle_path.exists() else {}
    points = s.operating_points(n_points)
    summary = summarize_pooled(list(done.values()), s, points, checked_at_points(s, n_points))
    if summary is None:
        raise SystemExit(
            f"no pooled oracle of {s.name} at {n_points} points in {oracle_path} (some point "
            f"has no checked set, or no set passed at every point); see "
            f"experiments/schedule_oracle.py --pooled"
        )
    best_values, table = pooled_sets(done, s, summary)
    return {
        "points": points,
        "table": table,
        "table_points": list(points),
        "table_checked": True,  # each row passed the check at its point
        "best_fixed_checked": True,
        "best_fixed": summary["best_fixed"],
        "best_fixed_values": best_values,
        "robust_values": None,
        "oracle_costs": summary["oracle_costs"],
        "oracle_mean_cost": summary["oracle_mean_cost"],
        "best_fixed_point_mean_cost": summary["best_fixed_mean_cost"],
        "oracle_gap": summary["oracle_gap"],
        "checks_passed": {m: True for m in summary["pool"]},
        "checked_at": summary["checked_at"],
        "oracle_from": summary["oracle_from"],
    }


# -- training -------------------------------------------------------------------------------


def hyperparameters(algo: str, env_id: str) -> dict[str, Any]:
    """The RL Zoo file's hyperparameters of ``env_id`` as SB3 keyword arguments."""
    import yaml

    path = ROOT / "servogym" / "agents" / "hyperparams" / f"{algo}.yml"
    doc = yaml.safe_load(path.read_text())
    hp = dict(doc.get(env_id, doc["default"]))
    for key in ("n_timesteps", "policy", "n_envs", "normalize"):
        hp.pop(key, None)
    if isinstance(hp.get("policy_kwargs"), str):  # "dict(net_arch=[128, 128])"
        call = ast.parse(hp["policy_kwargs"], mode="eval").body
        if not (isinstance(call, ast.Call) and getattr(call.func, "id", None) == "dict"
                and not call.args):  # fmt: skip
            raise SystemExit(f"{path}: policy_kwargs must be dict(key=literal, ...)")
        hp["policy_kwargs"] = {kw.arg: ast.literal_eval(kw.value) for kw in call.keywords}
    return hp


def algo_of(s: Any, algo: str | None) -> str:
    return algo or ("ppo" if s.stored_sets else "sac")


def train_policy(s: Any, env_id: str, base: dict[str, Any], args: argparse.Namespace) -> Path:
    """Train (or resume, or find trained) the scenario's policy; its ``model.zip``."""
    from servogym.agents import train

    algo = algo_of(s, args.algo)
    out = args.runs / f"{s.name}-{algo}-{args.center}-s{args.seed}"
    if s.stored_sets:
        env_kwargs: dict[str, Any] = {}
    elif args.center == "table":
        from servogym.envs._machine import is_machine

        if is_machine(s.plant):
            raise SystemExit(
                f"{s.name}: --center table needs a single-axis plant (center_table); give "
                f"--center best-fixed, or --skip-train for the baselines."
            )
        table = [[p, v] for p, v in base["table"]]
        env_kwargs = {"center_table": table, "residual_scale": args.residual_scale}
    else:
        env_kwargs = {"center": base["best_fixed_values"], "residual_scale": args.residual_scale}
    budget_s = args.minutes * 60.0
    cfg_path = out / "config.json"
    spent, trained = 0.0, 0
    if cfg_path.exists() and (out / "model.zip").exists():
        cfg = json.loads(cfg_path.read_text())
        spent, trained = float(cfg.get("wall_time_s", 0.0)), int(cfg["trained_timesteps"])
        if cfg.get("env_kwargs") != env_kwargs:
            raise SystemExit(
                f"{out} trained around another centre ({cfg.get('env_kwargs')}); the oracle "
                f"study changed? Move the folder away to train again."
            )
    if trained > 0 and (
        spent >= budget_s - min(30.0, 0.05 * budget_s) or trained >= args.timesteps
    ):
        print(f"{s.name}: {algo} trained already ({trained} steps, {spent / 60:.1f} min)")
        return out / "model.zip"
    print(f"{s.name}: training {algo} for {(budget_s - spent) / 60:.1f} min more "
          f"({trained} steps so far) in {out}", flush=True)  # fmt: skip
    return train(
        env_id, algo, args.timesteps, args.seed, out, n_envs=2, env_kwargs=env_kwargs,
        algo_kwargs=hyperparameters(algo, env_id), checkpoint_every=5000,
        wall_time_s=budget_s - spent, progress_bar=False, log_progress=True,
        resume=trained > 0,
    )  # fmt: skip


# -- evaluation -----------------------------------------------------------------------------


def _policy_env(env_id: str, name: str, model: str | None, base: dict[str, Any]):
    """``(env, policy)`` of one named policy on the default integration."""
    import gymnasium as gym

    import servogym  # noqa: F401
    from servogym.agents import ConstantPolicy, GainTablePolicy

    if name == "policy":
        from servogym.agents._train import load_policy, read_config, run_env_kwargs

        config = read_config(Path(model).parent / "config.json")
        env = gym.make(env_id, **run_env_kwargs(config), reward_scale=1.0)
        return env, load_policy(model)
    env = gym.make(env_id, action_type="unit", reward_scale=1.0)
    u = env.unwrapped
    if name == "gain_table":
        return env, GainTablePolicy(env, base["table"])
    return env, ConstantPolicy(u.actions.from_values(base[f"{name}_values"]))


def run_block(job: dict[str, Any]) -> dict[str, Any]:
    """One policy's held-out episodes on one integration (a worker process)."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from servogym.agents import reference_env
    from servogym.agents._train import set_torch_threads

    set_torch_threads(1)
    env, policy = _policy_env(job["env_id"], job["policy"], job.get("model"), job["base"])
    if job["integration"] == "reference":
        env = reference_env(env)
        if job["policy"] == "gain_table":
            from servogym.agents import GainTablePolicy

            policy = GainTablePolicy(env, job["base"]["table"])
    u = env.unwrapped
    t0 = time.perf_counter()
    costs, diverged, refused, emitted = [], [], 0, set()
    for seed in range(job["seed0"], job["seed0"] + job["episodes"]):
        obs, _ = env.reset(seed=seed)
        total, done, div = 0.0, False, False
        while not done:
            obs, _, term, trunc, info = env.step(policy(obs))
            total += float(info["raw_reward"])
            div |= bool(info["diverged"])
            values = {k: int(v) for k, v in info["params"].items()}
            key = tuple(sorted(values.items()))
            if key not in emitted:
                emitted.add(key)
                try:
                    u.scenario.params(values)  # the chip's own validation of every register
                except ValueError:
                    refused += 1
            done = term or trunc
        costs.append(-total / u.n_moves)
        diverged.append(div)
    env.close()
    return {**{k: job[k] for k in ("scenario", "policy", "integration", "seed0", "episodes",
                                   "key")},
            "costs": costs, "diverged": diverged, "distinct_sets": len(emitted),
            "refused_sets": refused, "elapsed_s": time.perf_counter() - t0}  # fmt: skip


def bootstrap_mean(x: np.ndarray) -> list[float]:
    from scipy.stats import bootstrap

    if np.all(x == x[0]):
        return [float(x[0]), float(x[0])]
    ci = bootstrap((x,), np.mean, n_resamples=4000, confidence_level=0.95,
                   random_state=np.random.default_rng(0)).confidence_interval  # fmt: skip
    return [float(ci.low), float(ci.high)]


def bootstrap_ratio(a: np.ndarray, b: np.ndarray) -> list[float]:
    """95 % interval of mean(a) / mean(b), episodes resampled in pairs (same seeds)."""
    from scipy.stats import bootstrap

    def stat(x, y, axis=-1):
        return np.mean(x, axis=axis) / np.mean(y, axis=axis)

    ci = bootstrap((a, b), stat, paired=True, vectorized=True, n_resamples=4000,
                   confidence_level=0.95, random_state=np.random.default_rng(0),
                   method="percentile").confidence_interval  # fmt: skip
    return [float(ci.low), float(ci.high)]


def scenario_row(
    s: Any,
    env_id: str,
    base: dict[str, Any],
    blocks: dict[tuple, dict],
    run: dict[str, Any] | None,
    args: argparse.Namespace,
) -> dict[str, Any]:
    """The summary row of one scenario from its blocks of episodes."""
    per: dict[str, dict[str, Any]] = {}
    for integ in args.integrations.split(","):
        names = [n for n in _policies(run, base) if (n, integ) in blocks]
        res = {name: blocks[(name, integ)] for name in names}
        costs = {name: np.asarray(r["costs"]) for name, r in res.items()}
        row: dict[str, Any] = {}
        for name, c in costs.items():
            row[f"{name}_mean_cost"] = float(c.mean())
            row[f"{name}_ci95"] = bootstrap_mean(c)
            row[f"{name}_diverged_episodes"] = int(sum(res[name]["diverged"]))
            row[f"{name}_refused_sets"] = int(res[name]["refused_sets"])
            row[f"{name}_distinct_sets"] = int(res[name]["distinct_sets"])
        if "policy" in costs:
            for other in ("best_fixed", "gain_table"):
                row[f"policy_over_{other}"] = float(costs["policy"].mean() / costs[other].mean())
                row[f"policy_over_{other}_ci95"] = bootstrap_ratio(costs["policy"], costs[other])
        per[integ] = row
    headline = per.get("reference", per.get("default", {}))
    out = {
        "scenario": s.name,
        "env_id": env_id,
        "episodes": args.episodes,
        "eval_seeds": [args.eval_seed, args.eval_seed + args.episodes - 1],
        "integration": "reference" if "reference" in per else "default",
        "policy_mean_cost": headline.get("policy_mean_cost"),
        "best_fixed_mean_cost": headline.get("best_fixed_mean_cost"),
        "gain_table_mean_cost": headline.get("gain_table_mean_cost"),
        "robust_mean_cost": headline.get(
            "best_fixed_mean_cost" if base["best_fixed"] == "robust" else "robust_mean_cost"
        ),  # None with --oracle-label pooled: no robust set of its own
        "oracle_mean_cost": base["oracle_mean_cost"],
        "oracle_basis": oracle_basis(base),
        "oracle_gap": base["oracle_gap"],
        "best_fixed": base["best_fixed"],
        "points": base["points"],
        "gain_table_points": base["table_points"],
        "gain_table_checked": base["table_checked"],
        "best_fixed_checked": base["best_fixed_checked"],
        "oracle_checks_passed": base["checks_passed"],
        **{k: base[k] for k in ("oracle_from", "checked_at") if k in base},  # pooled only
        **{k: v for k, v in headline.items() if k.startswith("policy_over")},
        "by_integration": per,
    }
    if run is not None:
        out["policy_run"] = run
        goal = headline.get("policy_over_best_fixed")
        out["goal_met"] = bool(
            goal is not None and goal <= 0.7
            and headline["policy_mean_cost"] < headline["gain_table_mean_cost"]
        )  # fmt: skip
    out["command"] = (
        f".venv/bin/python experiments/schedule_policies.py --scenarios {s.name} "
        f"--minutes {args.minutes:g} --seed {args.seed} --episodes {args.episodes} "
        f"--center {args.center} --residual-scale {args.residual_scale:g} "
        + (f"--algo {args.algo} " if args.algo else "")
        + f"--oracle-label {args.oracle_label} --oracle-budget {args.oracle_budget}"
        + (" --skip-train" if args.skip_train else "")
    )
    return out


def oracle_basis(base: dict[str, Any]) -> str:
    """What a summary row's oracle cost is (the oracle study's cross-evaluation)."""
    sets = ("cheapest set that passed the check there, of every run (pooled)"
            if "oracle_from" in base else "own set at that point")  # fmt: skip
    return (f"operating points: each of the {len(base['points'])} points' {sets} (nominal "
            "plant otherwise), the oracle study's cross-evaluation; not episodes")  # fmt: skip


def _shown(path: Path) -> str:
    """A run folder as the summary names it: from ``experiments/`` on when it is in one
    (wherever the checkout is), else as given."""
    parts = path.resolve().parts
    if "experiments" in parts:
        return "/".join(parts[len(parts) - parts[::-1].index("experiments") - 1 :])
    return str(path)


def _run_tag(run: dict[str, Any]) -> str:
    """A trained policy's part of its episode blocks' key: run folder and steps trained."""
    return f"@{Path(run['folder']).name}@{run['trained_timesteps']}"


def _block_key(scenario: str, name: str, integ: str, run: dict[str, Any] | None,
               args: argparse.Namespace, base: dict[str, Any]) -> str:  # fmt: skip
    """The key of one policy's block of episodes in ``--episodes-out``. A pooled study's
    names its sets (the pool grows with every run)."""
    tag = _run_tag(run) if name == "policy" else ""
    sets = (f"|{base['best_fixed']}|{','.join(base['oracle_from'])}"
            if "oracle_from" in base else "")  # fmt: skip
    return (f"{scenario}|{name}{tag}|{integ}|{args.eval_seed}|{args.episodes}|"
            f"{args.oracle_label}|{args.oracle_budget}{sets}")  # fmt: skip


def _row_key(row: dict[str, Any]) -> tuple[str, str | None]:
    """A summary row's identity: the scenario and the policy's run folder (None: baselines)."""
    return row["scenario"], (row.get("policy_run") or {}).get("folder")


def _policies(run: dict[str, Any] | None, base: dict[str, Any]) -> list[str]:
    """The policies evaluated: the trained one, best fixed, the robust set when it is not the
    best fixed one, the gain table."""
    own = base["best_fixed"] == "robust" or base.get("robust_values") is None
    robust = [] if own else ["robust"]
    return (["policy"] if run is not None else []) + ["best_fixed", *robust, "gain_table"]


def _done(path: Path) -> dict[str, dict[str, Any]]:
    out = {}
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue  # torn by a kill: run again
            out[rec["key"]] = rec
    return out


TABLE_MARKERS = (
    "<!-- schedule policies table: experiments/results/schedule/summary.json -->",
    "<!-- end of schedule policies table -->",
)
"""The lines around the table of docs/envs.md that :func:`table` writes."""


def _fmt(mean: float | None, ci: list[float] | None = None) -> str:
    if mean is None:
        return "-"
    return f"{mean:.3g}" + (f" [{ci[0]:.3g}, {ci[1]:.3g}]" if ci else "")


def table(doc: dict[str, Any]) -> str:
    """The markdown table of docs/envs.md ("Policies against the baselines") from a summary
    (``--out``): per row, mean costs per move on the headline integration with their
    bootstrap intervals; a row of baselines only has no policy."""
    lines = [
        "| Env id | Policy (training) | Policy | Best fixed | Gain table | Oracle (points) | "
        "Policy / best fixed | Policy / gain table | Goal |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in doc["scenarios"]:
        per = r["by_integration"][r["integration"]]
        run = r.get("policy_run")
        if run is None:
            training = "none (baselines)"
        else:
            kw = run.get("env_kwargs") or {}
            how = ("around the gain table" if "center_table" in kw
                   else "around the best fixed set" if "center" in kw
                   else "choosing a stored set")  # fmt: skip
            minutes = (run.get("wall_time_s") or 0.0) / 60.0
            training = (
                f"{run['algo'].upper()} {how}, {run['trained_timesteps']} steps in "
                f"{minutes:.0f} min"
            )
        goal = "-" if "goal_met" not in r else ("met" if r["goal_met"] else "not met")
        cells = [
            f"`{r['env_id']}`",
            training,
            _fmt(per.get("policy_mean_cost"), per.get("policy_ci95")),
            _fmt(per.get("best_fixed_mean_cost"), per.get("best_fixed_ci95")),
            _fmt(per.get("gain_table_mean_cost"), per.get("gain_table_ci95")),
            _fmt(r["oracle_mean_cost"]),
            _fmt(per.get("policy_over_best_fixed"), per.get("policy_over_best_fixed_ci95")),
            _fmt(per.get("policy_over_gain_table"), per.get("policy_over_gain_table_ci95")),
            goal,
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_table(doc: dict[str, Any], path: Path) -> None:
    """Replace the table between :data:`TABLE_MARKERS` in ``path`` (docs/envs.md)."""
    text = path.read_text()
    head, sep, rest = text.partition(TABLE_MARKERS[0] + "\n")
    _, sep2, tail = rest.partition(TABLE_MARKERS[1])
    if not (sep and sep2):
        raise SystemExit(f"{path}: the markers {TABLE_MARKERS} are not both there.")
    tmp = path.with_suffix(".tmp")
    tmp.write_text(head + sep + table(doc) + "\n" + sep2 + tail)
    tmp.replace(path)


def main(argv: list[str] | None = None) -> None:
    args = _parse(argv)
    if args.table_only:
        write_table(json.loads(args.out.read_text()), args.docs)
        print(f"wrote the table of {args.out} into {args.docs}")
        return
    from servogym.envs._scenarios import SCENARIOS

    if str(HERE) not in sys.path:
        sys.path.insert(0, str(HERE))
    from schedule_oracle import _scenario_id, get_any_scenario

    names = args.scenarios.split(",") if args.scenarios else list(SCENARIOS)
    done = _done(args.episodes_out)
    rows = []
    for s in (get_any_scenario(n.strip()) for n in names):
        env_id = _scenario_id(s)
        base = baselines(s, args.oracle, args.oracle_label, args.oracle_budget)
        run = None
        model = None
        if not args.skip_train:
            model = str(train_policy(s, env_id, base, args))
            cfg = json.loads((Path(model).parent / "config.json").read_text())
            run = {"algo": cfg["algo"], "folder": _shown(Path(model).parent),
                   "trained_timesteps": cfg["trained_timesteps"],
                   "wall_time_s": cfg.get("wall_time_s"), "env_kwargs": cfg["env_kwargs"],
                   "algo_kwargs": cfg["algo_kwargs"]}  # fmt: skip
        jobs = []
        for name in _policies(run, base):
            for integ in args.integrations.split(","):
                key = _block_key(s.name, name, integ, run, args, base)
                if key in done:
                    continue
                jobs.append({"scenario": s.name, "env_id": env_id, "policy": name,
                             "integration": integ, "seed0": args.eval_seed,
                             "episodes": args.episodes, "key": key, "model": model,
                             "base": base})  # fmt: skip
        # the slow reference blocks first, so the two processes finish together
        jobs.sort(key=lambda j: j["integration"] != "reference")
        with ProcessPoolExecutor(args.workers) as pool:
            for rec in pool.map(run_block, jobs):
                args.episodes_out.parent.mkdir(parents=True, exist_ok=True)
                with args.episodes_out.open("a") as f:
                    f.write(json.dumps(rec) + "\n")
                done[rec["key"]] = rec
                print(f"{s.name} {rec['policy']} ({rec['integration']}): mean cost "
                      f"{np.mean(rec['costs']):.4g}, {sum(rec['diverged'])} diverged, "
                      f"{rec['refused_sets']} refused sets ({rec['elapsed_s']:.0f} s)",
                      flush=True)  # fmt: skip
        blocks = {}
        for name in _policies(run, base):
            for integ in args.integrations.split(","):
                blocks[(name, integ)] = done[_block_key(s.name, name, integ, run, args, base)]
        row = scenario_row(s, env_id, base, blocks, run, args)
        rows.append(row)
        print(json.dumps({k: row[k] for k in row if "mean_cost" in k or k.startswith(
            "policy_over") or k == "goal_met"}, indent=1), flush=True)  # fmt: skip
    old = json.loads(args.out.read_text()) if args.out.exists() else {"scenarios": []}
    mine = {_row_key(r) for r in rows}
    keep = [o for o in old.get("scenarios", []) if _row_key(o) not in mine]
    doc = {"scenarios": sorted(keep + rows, key=lambda r: (r["scenario"], str(_row_key(r)[1])))}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    tmp.replace(args.out)
    print(f"wrote {args.out}")
    if args.out.resolve() == (RESULTS / "summary.json").resolve() and args.docs.exists():
        write_table(doc, args.docs)  # the committed summary's table, not a scratch run's
        print(f"wrote its table into {args.docs}")


if __name__ == "__main__":
    main()
