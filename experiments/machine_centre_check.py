"""Do the multi-axis Schedule ids' safe centres pass ``servogym check``?

A Schedule id's residual action acts around its centre: the zero action runs that set on
every move. The single-axis scenarios' centres are robust sets that passed the check
(``servogym.envs._scenarios``); the multi-axis ids' centres
(``servogym.envs._machine.MACHINE_CENTERS``) were searched on episode cost alone
(``experiments/machine_schedule_centres.py``). This script puts a set
through the multi-axis check at ``--points`` operating points of the id's cycle (the
payload log-spaced from the empty gripper to the part range's high end, the other
parameters nominal: the points ``experiments/schedule_oracle.py`` tunes at), on the
machine's default tasks:

    .venv/bin/python experiments/machine_centre_check.py                 # every machine id
    .venv/bin/python experiments/machine_centre_check.py \\
        --ids servogym/Schedule-PMD-TwoLinkArm-v1 --sets oracle:chain-150  # an oracle set
    .venv/bin/python experiments/machine_centre_check.py --costs   # cost per move at zero

``--sets centre`` (the default) checks the centres of ``--version``'s ids;
``--sets margins`` checks each centre moved into the check's margins at every point at once
by a search on the check's linear analysis (``machine_margin_search.py``; no simulation;
``margins:oracle:<label>:<point>`` starts from that oracle set instead);
``--sets oracle:<label>`` checks instead the robust set of ``schedule_oracle.py``'s run of that
label (a candidate replacement; ``oracle:<label>:<point>``: the set tuned for that point);
``--sets ff:<sets>`` checks the set of ``<sets>``'s lines with its feed-forward registers
fitted on the check's tasks until their following error clears its limit at every point
(the loop gains, and so the margins, kept: ``machine_margin_search.fit_feed_forward``;
``ff-t<target>:<sets>`` fits until the worst following error / limit is ``<target>``
(or for 60 candidates, keeping the best if it is under :data:`FF_TARGET`) instead of
:data:`FF_TARGET`, for a set whose contouring error, which follows the following
error, makes its episodes costly);
``--sets detuned`` checks the centre with its loop gain scaled down
(:data:`DETUNE_REGISTERS` times each of :data:`DETUNE_SCALES` in turn, the heaviest point
first) until a scale passes at every point: what an engineer does with a set that rings,
and a candidate replacement that needs no tuning.

Resumable: one JSON line per (id, set, point) in ``--out``
(``experiments/results/schedule/machine_centre_checks.jsonl``); a re-run skips what is there.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

if str(Path(__file__).parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).parent))

import schedule_oracle as so

from servogym._registration import id_version

RESULTS = Path(__file__).parent / "results" / "schedule"


def machine_ids(version: int) -> list[str]:
    """Every multi-axis Schedule id of ``version``, in registry order."""
    from servogym import _registration as r

    return [
        r.make_id("Schedule", family_id, plant, version)
        for family_id, _ in r.BUILTIN_FAMILIES.values()
        for plant in r.BUILTIN_MACHINE_PLANTS
    ]


DETUNE_REGISTERS: dict[str, tuple[str, ...]] = {
    "pmd": ("kp", "ki", "kd"),
    "pmac": ("proportional_gain",),
    "parker6k": ("sgp", "sgi", "sgv"),
}
"""Per chip family, the registers whose common scale is the loop gain: PMD's feedback terms
(the feed-forward and Kout kept), PMAC's Ixx30 (it multiplies the whole servo sum), the
6250's parallel P, I and velocity-feedback gains (docs/chips/parker6k.md, section 4)."""

DETUNE_SCALES: tuple[float, ...] = (1.0, 2**-0.5, 0.5, 2**-1.5, 0.25, 2**-2.5, 0.125)
"""Loop-gain scales tried in turn, 3 dB apart (the first that passes everywhere is kept; 1:
the centre itself, whose lines are ``--sets centre``'s)."""


def detuned(values: dict[str, int], family: str, scale: float) -> dict[str, int]:
    """``values`` with every axis's :data:`DETUNE_REGISTERS` times ``scale`` (rounded; a
    non-zero gain stays >= 1)."""
    regs = DETUNE_REGISTERS[family]
    out = dict(values)
    for name, v in values.items():
        if name.split(".", 1)[0] in regs and v:
            out[name] = max(1, round(v * scale))
    return out


def oracle_set(s, label: str, path: Path) -> dict[str, int]:
    """The set of ``schedule_oracle.py``'s run ``label`` on scenario ``s``: its robust one, or
    with ``label`` ``<label>:<point>`` the set tuned for that point."""
    name = label if ":" in label else f"{label}:robust"
    return so.recorded_set(so._done(path), s, name, "--sets oracle:<label>:<point> =")


def check_at(s, values: dict[str, int], point: float, workers: int) -> dict[str, Any]:
    """The multi-axis check of ``values`` at ``point`` (the tuning problem's limits)."""
    config = so._config(s, so.point_args(workers), point)
    problem = config.problem()
    report = problem.check(problem.space.make_params(values), config.check_limits(),
                           workers=workers)  # fmt: skip
    worst = {axis: {k: {"value": float(v["value"]), "case": str(v["case"])}
                    for k, v in w.items()} for axis, w in report.worst.items()}  # fmt: skip
    return {"passed": bool(report.passed), "failures": list(report.failures)[:8],
            "worst": worst, "elapsed_s": float(report.elapsed_s)}  # fmt: skip


def zero_action_cost(
    env_id: str,
    seeds: tuple[int, ...] = (0, 1),
    moves: int = 4,
    center: dict[str, int] | None = None,
) -> float:
    """The id's mean cost per move at the zero action (its centre, or ``center``, on every
    move) over ``seeds`` episodes of ``moves`` moves: the measure of the centres' tables in
    docs/envs.md (``experiments/machine_schedule_centres.py``'s objective, whose episode loop
    this is)."""
    import gymnasium as gym
    import numpy as np
    from machine_schedule_centres import episode_cost

    env = gym.make(env_id, n_moves=moves, **({} if center is None else {"center": center}))
    return episode_cost(env, np.zeros(env.action_space.shape, np.float32), list(seeds))


def load_done(path: Path) -> dict[tuple, dict[str, Any]]:
    """The lines of ``path`` by (env id, ``--sets`` label, points, point); a line torn by a
    kill is left out (checked again)."""
    done: dict[tuple, dict[str, Any]] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                r = json.loads(line)
            except json.JSONDecodeError:
                continue
            done[(r["env_id"], r["sets"], r["points"], r["point"])] = r
    return done


def passed_everywhere(done: dict, eid: str, points: int) -> dict[str, dict[str, Any]]:
    """``--sets`` label -> one line, for every label whose one set passed the check at every
    one of ``points`` points on ``eid``."""
    by_label: dict[str, list[dict[str, Any]]] = {}
    for (e, label, n, _), r in done.items():
        if e == eid and n == points:
            by_label.setdefault(label, []).append(r)
    return {
        label: rs[0]
        for label, rs in by_label.items()
        if {r["point"] for r in rs if r["passed"]} == set(range(points))
        and len({json.dumps(r["values"], sort_keys=True) for r in rs}) == 1
    }


def candidates(done: dict, ids: list[str], points: int) -> None:
    """``--candidates``: per id, every set that passed the check at every point, with its
    cost per move at the zero action as the id's centre (the cheapest is the ``-v2`` id's
    centre, ``MACHINE_CENTERS_V2``), against the ``-v1`` centre's."""
    for eid in ids:
        print(f"{eid}: the -v1 centre {zero_action_cost(eid):.3g} per move", flush=True)
        rows = [(zero_action_cost(eid, center=r["values"]), label)
                for label, r in passed_everywhere(done, eid, points).items()]  # fmt: skip
        for cost, label in sorted(rows):
            print(f"  {cost:8.3g} per move  --sets {label}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ids", default=None, help="comma-separated env ids (default: every one)")
    ap.add_argument("--version", type=int, default=1, help="the ids' version (default: 1)")
    ap.add_argument(
        "--sets", default="centre",
        help="centre, detuned, margins, margins:oracle:<label>:<point> or oracle:<label>",
    )  # fmt: skip
    ap.add_argument("--points", type=int, default=3, help="operating points (>= 2)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--oracle", type=Path, default=RESULTS / "oracle.jsonl")
    ap.add_argument("--out", type=Path, default=RESULTS / "machine_centre_checks.jsonl")
    ap.add_argument(
        "--costs", action="store_true",
        help="print every machine Schedule id's cost per move at the zero action instead",
    )  # fmt: skip
    ap.add_argument(
        "--candidates", action="store_true",
        help="per id, every set that passed at every point, with its cost at the zero action",
    )  # fmt: skip
    args = ap.parse_args()
    if args.costs:
        from servogym._registration import MACHINE_SCHEDULE_VERSIONS

        for version in MACHINE_SCHEDULE_VERSIONS:
            for eid in machine_ids(version):
                print(f"{eid}: {zero_action_cost(eid):.3g} per move at the zero action", flush=True)
        return
    if args.points < 2:
        raise SystemExit(f"--points must be >= 2; got --points {args.points}.")
    if args.sets not in ("centre", "detuned", "margins") and not args.sets.startswith(
        ("oracle:", "margins:oracle:", "ff:", "ff-t")
    ):
        raise SystemExit(
            f"--sets must be centre, detuned, margins, margins:oracle:<label>:<point>, "
            f"ff[-t<target>]:<sets> or oracle:<label>[:<point>]; got --sets {args.sets}."
        )
    ids = args.ids.split(",") if args.ids else machine_ids(args.version)
    done = load_done(args.out)
    if args.candidates:
        candidates(done, [i.strip() for i in ids], args.points)
        return
    for eid in ids:
        s = so.machine_scenario(eid.strip())
        points = s.operating_points(args.points)
        if args.sets == "detuned":
            centre = so.machine_center(s)
            for scale in DETUNE_SCALES:
                label = "centre" if scale == 1.0 else f"detuned:{scale:.3f}"
                order = list(range(len(points)))[::-1]  # the heaviest first: it fails first
                if all(_run(args, done, eid, s, label, detuned(centre, s.family, scale), i,
                            points[i]) for i in order):  # fmt: skip
                    print(f"{eid}: the centre times {scale:.3f} passes at every point", flush=True)
                    break
            else:
                print(f"{eid}: no scale down to {DETUNE_SCALES[-1]} passes", flush=True)
            continue
        if args.sets.startswith(("ff:", "ff-t")):
            feed_forward(args, done, eid, s, points)
            continue
        if args.sets.startswith("margins"):
            label = args.sets
            prev = [done.get((eid, label, args.points, i)) for i in range(len(points))]
            values = next((p["values"] for p in prev if p), None)
            extra: dict[str, Any] = {}
            if values is None:
                start = (
                    so.machine_center(s) if label == "margins"
                    else oracle_set(s, label.split(":", 2)[2], args.oracle)
                )  # fmt: skip
                moved = margins_centre(s, points, args.workers, start)
                extra = {"margin_search": {k: w for k, w in moved.items() if k != "values"}}
                print(f"{eid}: margin search from {label}: slack {moved['start_slack']:.3g} "
                      f"-> {moved['slack']:.3g} ({moved['evaluations']} evaluations, "
                      f"{moved['search_s']:.0f} s)", flush=True)  # fmt: skip
                values = moved["values"]
                if values is None:
                    continue
            passed = [_run(args, done, eid, s, label, values, i, v, extra)
                      for i, v in enumerate(points)]  # fmt: skip
            oracle_names = {name for name, _ in so.MACHINE_SCENARIOS}  # the PMD ids only
            if (all(passed) and s.name in oracle_names
                    and eid == so._scenario_id(so.get_any_scenario(s.name))):  # fmt: skip
                record_for_oracle(s, label, values, points, args)
            continue
        if args.sets == "centre":
            values = so.machine_center(s, id_version(eid.strip()))
        else:
            values = oracle_set(s, args.sets.split(":", 1)[1], args.oracle)
        for i, v in enumerate(points):
            _run(args, done, eid, s, args.sets, values, i, v)


FF_TARGET = 0.85
"""The worst following error / its limit (and saturation / its maximum) that ``--sets ff:``
fits the feed-forward to: 15 % below the check's limits."""


def feed_forward(args, done: dict, eid: str, s, points: list[float]) -> bool:
    """``--sets ff:<sets>``: the set of ``<sets>``'s lines for ``eid`` with its feed-forward
    registers fitted until the tasks' following error and saturation clear their limits at
    every point (``machine_margin_search.fit_feed_forward``; the loop gains, and so the
    margins, kept), then checked at every point. Passed everywhere?"""
    from machine_margin_search import fit_feed_forward

    label, source = args.sets, args.sets.split(":", 1)[1]
    head = label.split(":", 1)[0]  # ff (the default target) or ff-t<target>
    try:
        target = float(head[len("ff-t") :]) if head.startswith("ff-t") else FF_TARGET
    except ValueError:
        target = float("nan")
    if not 0 < target <= FF_TARGET:
        raise SystemExit(f"--sets {label}: ff-t<target> needs 0 < target <= {FF_TARGET}.")
    prev = [done.get((eid, label, args.points, i)) for i in range(len(points))]
    values = next((p["values"] for p in prev if p), None)
    extra: dict[str, Any] = {}
    if values is None:
        start = next((r["values"] for (e, name, n, _), r in done.items()
                      if e == eid and name == source and n == args.points), None)  # fmt: skip
        if start is None:
            raise SystemExit(f"--sets {label}: no line of {eid} with sets {source!r} in "
                             f"{args.out} (check that set first).")  # fmt: skip
        config = so._config(s, so.point_args(args.workers), points[0])
        fit = fit_feed_forward(config.problem(), config.check_limits(), start,
                               plants=[{s.param: float(p)} for p in points], target=target,
                               accept=FF_TARGET, max_evals=60,
                               workers=args.workers)  # fmt: skip
        extra = {"feed_forward": {k: w for k, w in fit.items() if k not in ("values", "best")}}
        print(f"{eid}: feed-forward fit from {source}: worst ratio {fit['start_ratio']:.3g} "
              f"-> {fit['ratio']:.3g} ({fit['evaluations']} evaluations, "
              f"{fit['search_s']:.0f} s; {fit['where']})", flush=True)  # fmt: skip
        values = fit["values"]
        if values is None:
            return False
    return all([_run(args, done, eid, s, label, values, i, v, extra)
                for i, v in enumerate(points)])  # fmt: skip


def record_for_oracle(s, label: str, values: dict[str, int], points: list[float], args) -> None:
    """A set that passed the check at every point of the cycle, in the oracle study's records
    (point ``cycle``), so that ``schedule_oracle.py --pooled`` counts it."""
    cross = so.append_checked_set(args.oracle, s, label, "cycle", values, points, args.workers,
                                  value=None, checked_at=[float(p) for p in points])  # fmt: skip
    if cross is not None:
        print(f"recorded in {args.oracle}: cross {[round(c, 3) for c in cross]}", flush=True)


def margins_centre(s, points: list[float], workers: int, start: dict[str, int]) -> dict[str, Any]:
    """``start`` (the id's centre, or an oracle set) moved into the check's margins at every
    one of ``points`` at once (``machine_margin_search.move_into_margins`` on the check's
    linear analysis)."""
    from machine_margin_search import move_into_margins

    config = so._config(s, so.point_args(workers), points[0])
    plants = [{s.param: float(p)} for p in points]
    return move_into_margins(config.problem(), config.check_limits(), start,
                             plants=plants)  # fmt: skip


def _run(args, done: dict, eid: str, s, label: str, values: dict[str, int], i: int,
         v: float, extra: dict[str, Any] | None = None) -> bool:  # fmt: skip
    """Check ``values`` at point ``i`` unless a line has it; append the line; passed?"""
    key = (eid, label, args.points, i)
    if key in done:
        return done[key]["passed"]
    t0 = time.perf_counter()
    rec = {"env_id": eid, "sets": label, "points": args.points, "point": i, s.param: v,
           "values": values, **(extra or {}), **check_at(s, values, v, args.workers)}  # fmt: skip
    rec["wall_s"] = time.perf_counter() - t0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("a") as f:
        f.write(json.dumps(rec) + "\n")
    done[key] = rec
    gm, pm = (min(w[k]["value"] for w in rec["worst"].values())
              for k in ("gain_margin_db", "phase_margin_deg"))  # fmt: skip
    print(f"{eid} {label} {s.param}={v:.3g}: "
          f"{'passed' if rec['passed'] else 'FAILED'}; worst gain margin {gm:.3g} dB, "
          f"phase margin {pm:.3g} deg "
          f"({rec['wall_s']:.0f} s){'; ' + rec['failures'][0] if rec['failures'] else ''}",
          flush=True)  # fmt: skip
    return rec["passed"]


if __name__ == "__main__":
    main()
