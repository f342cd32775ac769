"""The oracle gap of every gain-scheduling scenario: how much one fixed set gives away.

    nice -n 10 .venv/bin/python experiments/schedule_oracle.py --budget 150      # the study
    nice -n 10 .venv/bin/python experiments/schedule_oracle.py --budget 30 --robust 4 \\
        --episodes 10 --label smoke                                             # a smoke run

For each scenario of ``servogym.envs.SCENARIOS`` and of :data:`MACHINE_SCENARIOS` (the
two-link arm; ``--scenarios`` picks some):

1. K operating points (``--points``, default 4): the scheduled parameter log-spaced from the
   empty value to the part range's high end, the other parameters nominal, the scenario's
   fixed values and moves;
2. per point, a set tuned there (``servogym tune``'s machinery: the model-based design start,
   ``--tuner`` over ``--budget`` evaluations with the margin and saturation constraints, then
   ``check_candidates``: the cheapest feasible trial that passes ``servogym check``, of at
   most ``--check-candidates`` tried; when none passes, tuned again with the margin
   constraints tightened by ``MARGIN_STEPS``);
3. a robust set: tuned over ``--robust`` plant draws from the scenario's whole distribution
   (the scheduled parameter over empty .. part high, the other drawn parameters over the
   scenario's ranges), mean cost, checked on those draws too;
4. every set cross-evaluated on every point (the accurate RK4 loop, ``Evaluator``);
5. ``--episodes`` seeded Schedule-env episodes of the robust set, the best fixed set and the
   gain table (before each move the set of the operating point nearest the measured
   condition, in log scale: what a controller with stored gain sets does; of the points
   whose set passed the check). ``experiments/schedule_policies.py`` runs the study's
   held-out episodes, on both integrations, with the trained policies.

On a multi-axis machine (``TwoLinkArm``) a set is every axis's registers (``kp.1``, ``kp.2``),
tuned by ``servogym tune``'s machine path on the plant's default tasks (coordinated moves and
contours) from the id's safe centre (:data:`servogym.envs._machine.MACHINE_CENTERS`: the
model-based design start has no machine model), checked by the multi-axis check, and
cross-evaluated on those tasks (``MachineEvaluator``).

The oracle gap is ``best fixed mean cost / oracle mean cost`` over the points: the best fixed
set is the candidate (robust or any point's set) that passed the check with the lowest mean
cost over the points (``best_fixed_checked`` is false when none passed and all were
candidates), the oracle uses each point's own set there. A set that diverges at a point costs the
divergence penalty there (1000 .. 2000), so it is never the best fixed set.

Resumable: every finished set is one JSON line in ``--out``
(``experiments/results/schedule/oracle.jsonl``), keyed by (scenario, point, budget, label);
a re-run skips what is there. The summary (``oracle_summary.json`` next to it) is rebuilt
from the lines at the end of every run.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

RESULTS = Path(__file__).parent / "results" / "schedule"


def _parse() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", default=None, help="comma-separated names (default: all)")
    ap.add_argument("--points", type=int, default=4, help="operating points K (>= 2)")
    ap.add_argument("--budget", type=int, default=150, help="evaluations per tuned set")
    ap.add_argument("--robust", type=int, default=8, help="plant draws of the robust set")
    ap.add_argument("--tuner", default=None, help="default: servogym tune's default (safe)")
    ap.add_argument("--episodes", type=int, default=100, help="Schedule-env episodes per policy")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--check-candidates", type=int, default=20,
        help="feasible trials checked, cheapest first, until one passes (tune's default: 5)",
    )  # fmt: skip
    ap.add_argument("--workers", type=int, default=1, help="evaluation threads per study")
    ap.add_argument("--label", default="full", help="a name stored with every line (smoke)")
    ap.add_argument(
        "--robust-only", action="store_true",
        help="tune only the robust set of each scenario (the residual action's centre)",
    )  # fmt: skip
    ap.add_argument(
        "--chain", action="store_true",
        help="on a machine, start each set from the checked set of the point before (the "
        "robust one from the best checked set) or the id's centre, whichever is feasible "
        "and cheaper there",
    )  # fmt: skip
    ap.add_argument(
        "--margin-start", action="store_true",
        help="on a machine, first move the warm start into the check's margins by a search "
        "on the check's linear analysis (experiments/machine_margin_search.py): the safe "
        "tuner cannot leave an infeasible start",
    )  # fmt: skip
    ap.add_argument(
        "--start-from", default=None, metavar="LABEL:POINT",
        help="with --chain on a machine, also probe this recorded set as a warm start "
        "(e.g. margins:oracle:margin-search:2:cycle, the set checked at every point)",
    )  # fmt: skip
    ap.add_argument(
        "--pooled", action="store_true",
        help="tune nothing: summarise every checked set of every label at these points (the "
        "best known at each point against the best fixed one; label 'pooled')",
    )  # fmt: skip
    ap.add_argument("--out", type=Path, default=RESULTS / "oracle.jsonl")
    args = ap.parse_args()
    if args.tuner is None:
        from servogym.autotune._tuners import DEFAULT_TUNER

        args.tuner = DEFAULT_TUNER
    for name in ("points", "budget", "robust", "episodes", "workers", "check_candidates"):
        low = 2 if name == "points" else 1
        if getattr(args, name) < low:
            flag = name.replace("_", "-")
            raise SystemExit(f"--{flag} must be >= {low}; got --{flag} {getattr(args, name)}.")
    return args


def _done(path: Path) -> dict[tuple, dict[str, Any]]:
    out: dict[tuple, dict[str, Any]] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line torn by a kill: that set is tuned again
            out[_key(rec)] = rec
    return out


def _key(rec: dict[str, Any]) -> tuple:
    return (rec["kind"], rec["scenario"], str(rec["point"]), rec["budget"], rec["label"],
            rec["points"])  # fmt: skip


def point_args(workers: int) -> argparse.Namespace:
    """What :func:`_config` reads for one point's problem when nothing is tuned (a check, a
    cross-evaluation, a margin search)."""
    from servogym.autotune._tuners import DEFAULT_TUNER

    return argparse.Namespace(budget=1, tuner=DEFAULT_TUNER, seed=0, workers=workers, robust=1,
                              check_candidates=1)  # fmt: skip


def append_checked_set(path: Path, s, label: str, point: int | str, values: dict[str, int],
                       points: list[float], workers: int,
                       **fields: Any) -> list[float] | None:  # fmt: skip
    """Append a set found outside a tuning run that passed the check (``fields``: where) to
    the records at ``path``, with its cross-evaluation at ``points``, unless a record has it,
    so that ``--pooled`` counts it among the checked sets known; its costs, or ``None``."""
    if ("set", s.name, str(point), None, label, len(points)) in _done(path):
        return None
    rec = {"kind": "set", "point": point, "scenario": s.name, "budget": None, "label": label,
           "points": len(points), "tuner": "margin-search", "values": values,
           "feasible": None, "check_passed": True, "check_failures": [], **fields,
           "cross": cross_costs(s, values, points, point_args(workers))}  # fmt: skip
    _append(path, rec)
    return rec["cross"]


def _append(path: Path, rec: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as f:
        f.write(json.dumps(rec) + "\n")


MACHINE_SCENARIOS: tuple[tuple[str, str], ...] = (("TwoLinkArm", "two-link-arm"),)
"""Scenario name -> multi-axis plant: the machines' Schedule ids
(``servogym/Schedule-PMD-TwoLinkArm-v1``, the newest), studied on the PMD family's id."""


def get_any_scenario(name: str) -> Any:
    """A scenario of ``servogym.envs.SCENARIOS`` or of :data:`MACHINE_SCENARIOS` (a
    ``ScheduleScenario`` built from the machine's Schedule id: its chip model, its cycle's
    parameter, empty value and part range, the id's box of the other drawn parameters)."""
    from servogym.envs._scenarios import SCENARIOS, get_scenario

    machines = dict(MACHINE_SCENARIOS)
    if name in SCENARIOS or name not in machines:
        return get_scenario(name)  # raises naming the scenarios for an unknown name
    from servogym._registration import MACHINE_VERSIONS

    return machine_scenario(f"servogym/Schedule-PMD-{name}-v{MACHINE_VERSIONS[-1]}")


def machine_scenario(env_id: str) -> Any:
    """The ``ScheduleScenario`` of a multi-axis Schedule id (``servogym/Schedule-PMAC-XyStage-v1``):
    its chip model, its cycle's parameter, empty value and part range, the id's box of the
    other drawn parameters."""
    import gymnasium as gym

    import servogym  # noqa: F401
    from servogym.envs._machine import MACHINE_CYCLES
    from servogym.envs._scenarios import ScheduleScenario

    env = gym.make(env_id)
    u = env.unwrapped
    plant, family = u.scenario.plant, u.chip.name
    cycle = MACHINE_CYCLES[plant]
    box = {k: tuple(v) for k, v in u.scenario.box().items() if k != cycle.param}
    name = env_id.split("/")[-1].split("-")[2]
    env.close()
    return ScheduleScenario(name=name, family=family, chip_model=u.scenario.chip_model,
                            plant=plant, param=cycle.param, empty=cycle.empty,
                            part=tuple(cycle.part), plant_range=box)  # fmt: skip


def _is_machine(s) -> bool:
    from servogym.envs._machine import is_machine

    return is_machine(s.plant)


def machine_center(s, version: int = 1) -> dict[str, int]:
    """The machine id's centre, every axis's registers (``kp.1``, ``kp.2``): the ``-v1``
    id's, or with ``version=2`` the ``-v2`` id's (the checked one)."""
    from servogym.envs._machine import MACHINE_CENTER_VERSIONS, axis_register

    sets = MACHINE_CENTER_VERSIONS[version][(s.family, s.plant)]
    return {axis_register(k, n): int(v) for k, d in enumerate(sets, 1) for n, v in d.items()}


def _config(s, args, point: float | None):
    from servogym.autotune._job import TuneConfig

    if _is_machine(s):
        values = dict(s.plant_values) if point is None else {**s.plant_values, s.param: point}
        ranges = {s.param: (s.empty, s.part[1]), **dict(s.plant_range)}
        return TuneConfig(chip=s.chip_model, plant=s.plant, out=Path("unused"),
                          budget=args.budget, tuner=args.tuner, plant_params=values,
                          plant_ranges=ranges if point is None else {}, seed=args.seed,
                          workers=args.workers, robust=args.robust if point is None else 1,
                          check_candidates=args.check_candidates)  # fmt: skip
    search = None
    if s.family == "parker6k":
        from servogym.chips.parker6k import GAIN_FIELDS

        search = tuple(GAIN_FIELDS)  # what a stored set holds
    if point is None:
        ranges = {s.param: (s.empty, s.part[1]), **dict(s.plant_range)}
        return TuneConfig(chip=s.chip_model, plant=s.plant, out=Path("unused"),
                          budget=args.budget, tuner=args.tuner, plant_params=dict(s.plant_values),
                          plant_ranges=ranges, seed=args.seed, workers=args.workers,
                          robust=args.robust, moves=s.all_moves, search=search,
                          check_candidates=args.check_candidates)  # fmt: skip
    values = {**dict(s.plant_values), s.param: point}
    return TuneConfig(chip=s.chip_model, plant=s.plant, out=Path("unused"), budget=args.budget,
                      tuner=args.tuner, plant_params=values, seed=args.seed,
                      workers=args.workers, moves=s.all_moves, search=search,
                      check_candidates=args.check_candidates)  # fmt: skip


MARGIN_STEPS: tuple[tuple[float, float], ...] = ((0.0, 0.0), (2.0, 6.0), (4.0, 12.0))
"""Extra (dB, degrees) on the tuning's margin constraints, tried in turn while no candidate
passes the check: what an engineer does when a set sits on the margins' edge and fails at
the load +-20 % (the check itself keeps the standard 6 dB / 30 degrees)."""


def tune_set(s, args, point: float | None,
             start: dict[str, int] | None = None) -> dict[str, Any]:  # fmt: skip
    """Tune and check one set (``point=None``: the robust one); return its record part.

    When no candidate passes the check, tune again with tighter margin constraints
    (:data:`MARGIN_STEPS`); the record keeps the extra margins the set was tuned with.
    """
    import dataclasses

    from servogym.autotune._job import check_candidates, design_start, run_study

    config = _config(s, args, point)
    t0 = time.perf_counter()
    tried = []
    for extra_db, extra_deg in MARGIN_STEPS:
        tune = dataclasses.replace(
            config,
            min_gain_margin_db=config.min_gain_margin_db + extra_db,
            min_phase_margin_deg=config.min_phase_margin_deg + extra_deg,
        )
        problem = tune.problem()
        if _is_machine(s):  # no machine model for the design: a checked set or the centre
            warm = start or machine_center(s)
        else:
            warm = design_start(problem, tune).get("values")
        result = run_study(problem, tune.tuner, tune.budget, storage=None,
                           n_workers=tune.workers, warm_start=warm)  # fmt: skip
        result, report = check_candidates(result, config)  # the standard check
        tried.append([extra_db, extra_deg, bool(report.passed)])
        if report.passed:
            break
    return {
        "values": {k: int(v) for k, v in result.best_values.items()},
        "tuned_cost": float(result.best.values[0]),
        "feasible": bool(result.feasible),
        "check_passed": bool(report.passed),
        "check_failures": list(report.failures)[:6],
        "margin_steps": tried,
        "elapsed_s": time.perf_counter() - t0,
    }


def chain_start(done: dict[tuple, dict[str, Any]], base: dict[str, Any],
                i: int | str) -> tuple[str, dict[str, int]] | None:  # fmt: skip
    """``--chain``'s warm start of set ``i`` on a machine: ``(which, values)`` of the set of
    the point before (``i - 1``) when it passed the check, for the robust set the checked set
    of lowest mean cross cost; ``None`` (the id's centre) otherwise. What an engineer does
    going from an empty gripper to a heavy part: start from the set that works next to it."""
    sets = {str(r["point"]): r for r in done.values() if r["kind"] == "set"
            and all(r[k] == v for k, v in base.items()) and r["check_passed"]}  # fmt: skip
    if i == "robust":
        if not sets:
            return None
        name = min(sets, key=lambda k: float(np.mean(sets[k]["cross"])))
        return name, sets[name]["values"]
    prev = str(int(i) - 1)
    return (prev, sets[prev]["values"]) if prev in sets else None


def pick_start(
    s, args, point: float | None, candidates: list[tuple[str, dict[str, int]]]
) -> tuple[str, dict[str, int], list]:
    """``--chain``'s warm start of a set on a machine: of ``candidates`` (``(name, values)``:
    the chain's set and the id's centre), the one feasible on the set's own tuning problem
    (every constraint met on its nominal plant, or its draws) at the lowest cost, else the
    cheapest; the safe tuner grows its region from the start, so an infeasible start leaves
    it nowhere to go.

    Returns ``(name, values, probes)``, ``probes`` each candidate's ``[name, cost,
    feasible]``."""
    from servogym.autotune._job import run_study
    from servogym.autotune._session import is_feasible

    config = _config(s, args, point)
    probes = []
    for name, values in candidates:
        result = run_study(config.problem(), config.tuner, 1, storage=None,
                           n_workers=1, warm_start=values)  # fmt: skip
        trial = result.trials[0]
        probes.append([name, float(trial.values[0]), bool(is_feasible(trial))])
    best = min(range(len(probes)), key=lambda k: (not probes[k][2], probes[k][1]))
    return candidates[best][0], candidates[best][1], probes


def recorded_set(done: dict[tuple, dict[str, Any]], s, name: str,
                 flag: str = "--start-from") -> dict[str, int]:  # fmt: skip
    """The values of the recorded set ``<label>:<point>`` of scenario ``s`` (the last one);
    ``flag`` names the option that asked for it in the error."""
    label, _, point = name.rpartition(":")
    found = [r for r in done.values() if r["kind"] == "set" and r["scenario"] == s.name
             and r["label"] == label and str(r["point"]) == point]  # fmt: skip
    if not found:
        raise SystemExit(f"{flag} {name}: no set {point!r} of label {label!r} for {s.name}")
    return {k: int(v) for k, v in found[-1]["values"].items()}


def margin_start(s, args, point: float | None, start: dict[str, int]) -> dict[str, Any]:
    """``--margin-start``: ``start`` moved into the check's margins on the set's own problem
    (its nominal plant, or for the robust set its draws), by
    ``machine_margin_search.move_into_margins``; ``values`` is ``None`` when the search
    did not reach its target slack."""
    from machine_margin_search import move_into_margins

    config = _config(s, args, point)
    problem = config.problem()
    # the check runs the nominal plant, then each draw (check_candidates' extra_plants)
    plants = [{}, *problem.plant_instances()] if problem.n_plants > 1 else None
    return move_into_margins(problem, config.check_limits(), start, plants=plants)


def cross_costs(s, values: dict[str, int], points: list[float], args) -> list[float]:
    """The set's cost at every operating point (nominal otherwise; the RK4 loop)."""
    from servogym.sim import Evaluator, Scenario

    if _is_machine(s):  # the machine's tasks, as tuned (the point's tuning problem)
        from servogym.autotune._machine import MachineEvaluator

        costs = []
        for v in points:
            problem = _config(s, args, v).problem()
            ev = MachineEvaluator(problem.scenario)
            costs.append(float(ev.evaluate(problem.space.make_params(values)).cost))
        return costs
    costs = []
    for v in points:
        sc = Scenario(s.chip_model, s.plant, {**dict(s.plant_values), s.param: v},
                      moves=s.all_moves)  # fmt: skip
        ev = Evaluator(sc)
        costs.append(float(ev.evaluate(sc.params(values)).cost))
    return costs


def episodes(s, policies: dict[str, Any], n: int, seed: int) -> dict[str, dict[str, float]]:
    """Mean per-move cost of each policy on ``n`` seeded Schedule-env episodes (the same
    seeds for all). A policy is a register-value dict (fixed) or a list of
    (operating point, values) (the gain table: nearest point to the coming move's load)."""
    import gymnasium as gym

    import servogym  # noqa: F401

    eid = _scenario_id(s)
    env = gym.make(eid, action_type="unit", reward_scale=1.0)
    u = env.unwrapped
    out = {}
    for name, pol in policies.items():
        costs, diverged = [], 0
        for ep in range(n):
            env.reset(seed=seed + 100_000 + ep)
            done = False
            ep_costs = []
            while not done:
                k = u._k
                load = u.part_value if k % 2 == 1 else u._empty
                if isinstance(pol, list):
                    values = min(pol, key=lambda pv: abs(math.log(pv[0] / load)))[1]
                else:
                    values = pol
                _, _, done, _, info = env.step(u.actions.from_values(values))
                ep_costs.append(float(info["cost"]))
                diverged += bool(info["diverged"])
            costs.append(float(np.mean(ep_costs)))
        out[name] = {"mean_cost": float(np.mean(costs)),
                     "sem": float(np.std(costs, ddof=1) / math.sqrt(n)) if n > 1 else 0.0,
                     "diverged_episodes": diverged, "episodes": n}  # fmt: skip
    env.close()
    return out


def _scenario_id(s) -> str:
    """The scenario's newest Schedule id."""
    from servogym._registration import BUILTIN_FAMILIES, MACHINE_VERSIONS, SCENARIO_VERSIONS

    version = (MACHINE_VERSIONS if _is_machine(s) else SCENARIO_VERSIONS)[-1]
    return f"servogym/Schedule-{BUILTIN_FAMILIES[s.family][0]}-{s.name}-v{version}"


def summarize(records: list[dict[str, Any]], s, points: list[float], label: str,
              budget: int) -> dict[str, Any] | None:  # fmt: skip
    sets = {str(r["point"]): r for r in records
            if r["kind"] == "set" and r["scenario"] == s.name and r["label"] == label
            and r["budget"] == budget and r["points"] == len(points)}  # fmt: skip
    need = [str(i) for i in range(len(points))] + ["robust"]
    if any(k not in sets for k in need):
        return None
    k = len(points)
    oracle = [sets[str(i)]["cross"][i] for i in range(k)]
    means = {name: float(np.mean(sets[name]["cross"])) for name in need}
    # the best fixed set of those that passed the check (an engineer stores no other)
    passed = [name for name in need if sets[name]["check_passed"]]
    best = min(passed or need, key=means.get)
    oracle_mean = float(np.mean(oracle))
    best_cross = sets[best]["cross"]
    return {
        "scenario": s.name,
        "env_id": _scenario_id(s),
        "label": label,
        "budget": budget,
        "param": s.param,
        "points": points,
        "oracle_costs": oracle,
        "oracle_mean_cost": oracle_mean,
        "robust_costs": sets["robust"]["cross"],
        "robust_mean_cost": means["robust"],
        "best_fixed": best,
        "best_fixed_costs": best_cross,
        "best_fixed_mean_cost": means[best],
        "best_fixed_checked": bool(sets[best]["check_passed"]),
        "oracle_gap": means[best] / oracle_mean,
        "oracle_gap_worst_point": max(b / o for b, o in zip(best_cross, oracle, strict=True)),
        "checks_passed": {name: sets[name]["check_passed"] for name in need},
        "sets_passing_everywhere": [
            name for name in need if sets[name]["check_passed"] and max(sets[name]["cross"]) < 1000
        ],
    }


def checked_at_points(s, n_points: int) -> dict[str, set[int]]:
    """Per oracle set (``<label>:<point>``), the points at which it passed the check in
    ``machine_centre_check.py --sets oracle:<label>:<point>``'s lines for the scenario's id."""
    path = RESULTS / "machine_centre_checks.jsonl"
    out: dict[str, set[int]] = {}
    if not path.exists():
        return out
    for line in path.read_text().splitlines():
        try:
            r = json.loads(line)
        except json.JSONDecodeError:
            continue
        if (r["env_id"] != _scenario_id(s) or r["points"] != n_points
                or not r["sets"].startswith("oracle:")):  # fmt: skip
            continue
        name = r["sets"].split(":", 1)[1]
        name = name if ":" in name else f"{name}:robust"
        if r["passed"]:
            out.setdefault(name, set()).add(int(r["point"]))
    return out


def summarize_pooled(
    records: list[dict[str, Any]], s, points: list[float], checked: dict | None = None
) -> dict[str, Any] | None:
    """The oracle gap from every checked set known for the scenario at these points, of any
    label (run) or tuner (the issue's "best set known at each payload"). A set counts at a
    point where it passed the check there: the point it was tuned for (its own check), the
    points of ``checked`` (``<label>:<point>`` -> point indices, from
    :func:`checked_at_points`) and those its record lists in ``checked_at``. The oracle at
    each point is the cheapest set that counts there (each set's cost at every point is its
    cross-evaluation); the best fixed set is the one of lowest mean among those that count at
    every point (a fixed set runs at every payload). ``None`` when some point has no set
    or no set counts everywhere."""
    checked = checked or {}
    n = len(points)
    pool = {f"{r['label']}:{r['point']}": r for r in records
            if r["kind"] == "set" and r["scenario"] == s.name and r["points"] == n
            and r.get("cross")}  # fmt: skip
    at: dict[str, set[int]] = {}
    for name, r in pool.items():
        ok = set(checked.get(name, set()))
        if r["check_passed"] and str(r["point"]).isdigit():
            ok.add(int(r["point"]))
        ok |= {i for i, p in enumerate(points) if float(p) in map(float, r.get("checked_at") or [])}
        if ok:
            at[name] = ok
    if any(not any(i in ok for ok in at.values()) for i in range(n)):
        return None
    fixed = sorted(name for name, ok in at.items() if len(ok) == n)
    if not fixed:
        return None
    oracle_from = [min((m for m in at if i in at[m]), key=lambda m, i=i: pool[m]["cross"][i])
                   for i in range(n)]  # fmt: skip
    oracle = [pool[m]["cross"][i] for i, m in enumerate(oracle_from)]
    means = {m: float(np.mean(pool[m]["cross"])) for m in at}
    best = min(fixed, key=means.get)
    best_cross = pool[best]["cross"]
    return {
        "scenario": s.name,
        "env_id": _scenario_id(s),
        "label": "pooled",
        "budget": None,
        "param": s.param,
        "points": points,
        "pool": sorted(at),
        "checked_at": {m: sorted(ok) for m, ok in sorted(at.items())},
        "oracle_from": oracle_from,
        "oracle_costs": oracle,
        "oracle_mean_cost": float(np.mean(oracle)),
        "best_fixed": best,
        "best_fixed_costs": best_cross,
        "best_fixed_mean_cost": means[best],
        "best_fixed_checked": True,
        "checked_everywhere": fixed,
        "oracle_gap": means[best] / float(np.mean(oracle)),
        "oracle_gap_worst_point": max(b / o for b, o in zip(best_cross, oracle, strict=True)),
    }


def pooled_sets(done: dict[tuple, dict[str, Any]], s,
                summary: dict[str, Any]) -> tuple[dict[str, int], list]:  # fmt: skip
    """The register values of a :func:`summarize_pooled` summary's sets: the best fixed set's,
    and the gain table (each point's oracle set: ``(point, values)`` rows)."""
    n = len(summary["points"])
    sets = {f"{r['label']}:{r['point']}": r for r in done.values() if r["kind"] == "set"
            and r["scenario"] == s.name and r["points"] == n}  # fmt: skip
    table = [(p, sets[m]["values"]) for p, m in zip(summary["points"], summary["oracle_from"],
                                                     strict=True)]  # fmt: skip
    return sets[summary["best_fixed"]]["values"], table


def main() -> None:
    args = _parse()
    from servogym.envs._scenarios import SCENARIOS

    names = args.scenarios.split(",") if args.scenarios else list(SCENARIOS)
    scenarios = [get_any_scenario(n.strip()) for n in names]
    done = _done(args.out)
    summary_path = args.out.with_name(args.out.stem + "_summary.json")
    summaries = []
    for s in scenarios:
        points = s.operating_points(args.points)
        base = {"scenario": s.name, "budget": args.budget, "label": args.label,
                "points": args.points}  # fmt: skip
        todo = [("robust", None)] if args.robust_only else [*enumerate(points), ("robust", None)]
        if args.pooled:
            todo = []  # no tuning: the summary of what the runs found
        for i, v in todo:
            rec = {"kind": "set", "point": i, **base}
            prev = done.get(_key(rec))
            if prev is not None and (prev["check_passed"] or "margin_steps" in prev):
                continue  # a set that failed before margin steps existed is tuned again
            t0 = time.perf_counter()
            rec |= {
                "value": v,
                "tuner": args.tuner,
                "robust": args.robust,
                "seed": args.seed,
                "check_candidates": args.check_candidates,
            }
            start = None
            if _is_machine(s) and args.chain:
                chained = chain_start(done, base, i)
                candidates = [chained] if chained else []
                candidates.append(("centre", machine_center(s)))
                if args.start_from:
                    candidates.append((args.start_from, recorded_set(done, s, args.start_from)))
                name, start, probes = pick_start(s, args, v, candidates)
                rec |= {"warm_start": name, "start_probes": probes}
            if _is_machine(s) and args.margin_start:
                start = start or machine_center(s)
                moved = margin_start(s, args, v, start)
                rec["margin_start"] = {k: w for k, w in moved.items() if k != "values"}
                if moved["values"] is not None and moved["values"] != start:
                    start = moved["values"]
                    rec["warm_start"] = rec.get("warm_start", "centre") + "+margins"
            rec |= tune_set(s, args, v, start)
            rec["cross"] = cross_costs(s, rec["values"], points, args)
            rec["elapsed_s"] = time.perf_counter() - t0
            _append(args.out, rec)
            done[_key(rec)] = rec
            print(f"{s.name} set {i}: tuned {rec['tuned_cost']:.4g}, check "
                  f"{'passed' if rec['check_passed'] else 'FAILED'}, cross "
                  f"{[round(c, 3) for c in rec['cross']]} ({rec['elapsed_s']:.0f} s)",
                  flush=True)  # fmt: skip
        if args.pooled:
            summary = summarize_pooled(list(done.values()), s, points,
                                       checked_at_points(s, len(points)))  # fmt: skip
            if summary is None:
                print(f"{s.name}: no checked set at some point; nothing pooled", flush=True)
                continue
            ep = {"kind": "episodes", "point": "pooled", "scenario": s.name, "budget": None,
                  "label": "pooled", "points": args.points, "pool": summary["pool"]}  # fmt: skip
            old = next((r for k, r in done.items() if r["kind"] == "episodes"
                        and r["point"] == "pooled" and r["scenario"] == s.name
                        and r.get("pool") == summary["pool"]), None)  # fmt: skip
            if old is None:
                best, table = pooled_sets(done, s, summary)
                policies = {"best_fixed": best, "gain_table": table}
                ep["results"] = episodes(s, policies, args.episodes, args.seed)
                _append(args.out, ep)
                done[_key(ep)] = ep
                old = ep
            summary["episodes"] = old["results"]
            summary["command"] = (
                f"nice -n 10 .venv/bin/python experiments/schedule_oracle.py --scenarios "
                f"{s.name} --points {args.points} --episodes {args.episodes} --seed "
                f"{args.seed} --pooled"
            )
            summaries.append(summary)
            print(f"{s.name}: pooled oracle gap {summary['oracle_gap']:.3g} (best fixed "
                  f"{summary['best_fixed']} {summary['best_fixed_mean_cost']:.4g} / oracle "
                  f"{summary['oracle_mean_cost']:.4g} from {summary['oracle_from']}); episodes "
                  f"{ {k: round(v['mean_cost'], 4) for k, v in summary['episodes'].items()} }",
                  flush=True)  # fmt: skip
            continue
        summary = summarize(list(done.values()), s, points, args.label, args.budget)
        if summary is None:
            continue
        ep = {"kind": "episodes", "point": "all", **base}
        if _key(ep) not in done:
            sets = {str(r["point"]): r for r in done.values() if r["kind"] == "set"
                    and all(r[k] == v for k, v in base.items())}  # fmt: skip
            rows = [i for i in range(len(points)) if sets[str(i)]["check_passed"]]
            rows = rows or list(range(len(points)))  # none passed: every set, flagged above
            table = [(points[i], sets[str(i)]["values"]) for i in rows]
            policies = {"robust": sets["robust"]["values"],
                        "best_fixed": sets[summary["best_fixed"]]["values"],
                        "gain_table": table}  # fmt: skip
            ep["results"] = episodes(s, policies, args.episodes, args.seed)
            _append(args.out, ep)
            done[_key(ep)] = ep
        summary["episodes"] = done[_key(ep)]["results"]
        summary["command"] = (
            f"nice -n 10 .venv/bin/python experiments/schedule_oracle.py --scenarios {s.name} "
            + " ".join(f"--{k} {getattr(args, k)}"
                       for k in ("points", "budget", "robust", "episodes", "seed", "label"))
            + (" --chain" if args.chain else "")
            + (" --margin-start" if args.margin_start else "")
            + (f" --start-from {args.start_from}" if args.start_from else "")
        )  # fmt: skip
        summaries.append(summary)
        print(f"{s.name}: oracle gap {summary['oracle_gap']:.3g} (best fixed "
              f"{summary['best_fixed']} {summary['best_fixed_mean_cost']:.4g} / oracle "
              f"{summary['oracle_mean_cost']:.4g}); episodes "
              f"{ {k: round(v['mean_cost'], 4) for k, v in summary['episodes'].items()} }",
              flush=True)  # fmt: skip
    old = json.loads(summary_path.read_text()) if summary_path.exists() else {"scenarios": []}
    keep = [o for o in old.get("scenarios", [])
            if (o["scenario"], o["label"], o["budget"]) not in
            {(x["scenario"], x["label"], x["budget"]) for x in summaries}]  # fmt: skip
    summary_path.write_text(json.dumps({"scenarios": keep + summaries}, indent=1) + "\n")
    print(f"wrote {summary_path}")


if __name__ == "__main__":
    main()
