"""Speed of the closed servo loop, measured against baselines in the same run.

    .venv/bin/python experiments/bench_servo_loop.py [--plant rotary] [--repeats 7]

Prints ticks per second (median of the repeats, with min..max) for:
  (a) a compiled loop of bare mj_step on the same plant, no controller;
  (b) the full closed loop (profile -> PMD filter -> amplifier -> mj_step -> encoder), one
      compiled call per episode (servogym.sim.ServoLoop);
  (c) the same closed loop as a plain Python loop (the Python reference filter, mj_step from
      Python: servogym/sim/_pyloop.py), and (c2) a Python loop that calls the compiled filter;
  (d) many short episodes on all cores (threads; the compiled loop releases the GIL), against
      the same episodes on one thread;
and the ratios b/a, b/c, b/c2 and d(all cores)/d(1 core). Targets (issue 3, rotary plant):
b/a >= 0.85, b/c >= 1.5, scaling >= 1.6 on 2 cores. Results: docs/performance.md.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import time
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np
from numba import njit

from servogym.chips.pmd import PMDParams, move
from servogym.chips.pmd._kernel import new_state, pmd_step
from servogym.chips.pmd._reference import PMDReferenceFilter
from servogym.plants import get_plant
from servogym.sim import ServoLoop
from servogym.sim._ffi import mj_step
from servogym.sim._pyloop import python_closed_loop
from servogym.sim._runner import TRAVEL_MARGIN, current_loop_alpha

PARAMS = PMDParams(model="MC2100", kp=40, kd=400, ki=10, derivative_time=1, kout=8000)


@njit(cache=True, nogil=True)
def bare_steps(m_addr, d_addr, qpos, ctrl, qpos_adr, ctrl_index, torque, n):
    """(a): read the encoder joint, write a constant torque, mj_step; n times."""
    s = 0.0
    for _ in range(n):
        s += qpos[qpos_adr]
        ctrl[ctrl_index] = torque
        mj_step(m_addr, d_addr)
    return s


def profile_for(plant, n_ticks: int):
    io = plant.io
    dt = PARAMS.sample_time_s
    rev = io.counts_per_unit * 2 * math.pi if io.travel_max > 1 else io.counts_per_unit * 0.05
    p = move("trapezoidal", 0, int(rev), 5 * rev, 200 * rev, dt, settle_ticks=1)
    reps = max(1, n_ticks // p.n_ticks)
    # Out and back, repeated, to fill n_ticks with motion.
    pos = np.concatenate([p.position if i % 2 == 0 else p.position[-1] - p.position
                          for i in range(reps)])[:n_ticks]  # fmt: skip
    vel = np.concatenate([p.velocity if i % 2 == 0 else -p.velocity for i in range(reps)])
    acc = np.concatenate([p.acceleration if i % 2 == 0 else -p.acceleration for i in range(reps)])
    return type(p)(pos, vel[: len(pos)], acc[: len(pos)], None, 0)


def timed(fn, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def rate(n: int, seconds: list[float]) -> dict[str, float]:
    rates = [n / s for s in seconds]
    return {"median": statistics.median(rates), "min": min(rates), "max": max(rates)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", default="rotary")
    ap.add_argument("--ticks", type=int, default=100_000, help="ticks per timed episode")
    ap.add_argument("--python-ticks", type=int, default=20_000)
    ap.add_argument("--episodes", type=int, default=400, help="short episodes for (d)")
    ap.add_argument("--episode-ticks", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--json", dest="json_out", help="also write the results here")
    args = ap.parse_args()

    family = get_plant(args.plant)
    plant = family.build()
    loop = ServoLoop(plant, PARAMS)
    io = plant.io
    prof = profile_for(plant, args.ticks)
    n = prof.n_ticks
    m, d = plant.model, plant.data

    # warm up every compiled function (and the numba cache)
    bare_steps(m._address, d._address, d.qpos, d.ctrl, io.qpos_adr, io.ctrl_index, 0.0, 10)
    loop.run(prof)

    def run_a():
        plant.reset()
        bare_steps(m._address, d._address, d.qpos, d.ctrl, io.qpos_adr, io.ctrl_index, 1e-3, n)

    def run_b():
        r = loop.run(prof)
        assert r.metrics.n_ticks == n, r.metrics

    pn = min(args.python_ticks, n)
    short = type(prof)(prof.position[:pn], prof.velocity[:pn], prof.acceleration[:pn], None, 0)
    span = io.travel_max - io.travel_min
    bounds = (io.travel_min + TRAVEL_MARGIN * span, io.travel_max - TRAVEL_MARGIN * span)
    max_err = min(int(span * io.counts_per_unit), 2**31 - 1)
    alpha = current_loop_alpha(io.current_bandwidth_hz, PARAMS.sample_time_s)

    def run_c():
        plant.reset()
        origin = int(np.floor(d.qpos[io.qpos_adr] * io.counts_per_unit))
        r = python_closed_loop(m, d, io, 1, *bounds, max_err, alpha, origin,
                               PMDReferenceFilter(PARAMS), short.position, short.velocity,
                               short.acceleration)  # fmt: skip
        assert r[0] == pn

    p_arr, a_arr = PARAMS.to_array(), loop._a

    def run_c2():
        plant.reset()
        state = new_state()
        origin = int(np.floor(d.qpos[io.qpos_adr] * io.counts_per_unit))
        cpu, kt, amps, peak = io.counts_per_unit, io.torque_constant_nm_per_a, \
            io.amp_amps_per_count, io.peak_current_a  # fmt: skip
        for k in range(pn):
            actual = ((math.floor(d.qpos[io.qpos_adr] * cpu) - origin + 2**31) % 2**32) - 2**31
            c = pmd_step(state, p_arr, a_arr, short.position[k], actual, short.velocity[k],
                         short.acceleration[k])  # fmt: skip
            d.ctrl[io.ctrl_index] = kt * min(max(c * amps, -peak), peak)
            mujoco.mj_step(m, d)

    results = {
        "a_bare_mj_step": rate(n, timed(run_a, args.repeats)),
        "b_closed_loop": rate(n, timed(run_b, args.repeats)),
        "c_python_loop": rate(pn, timed(run_c, max(3, args.repeats // 2))),
        "c2_python_loop_compiled_filter": rate(pn, timed(run_c2, max(3, args.repeats // 2))),
    }

    # (d) many short episodes: per-thread plants and loops, built before timing.
    ep = type(prof)(prof.position[: args.episode_ticks], prof.velocity[: args.episode_ticks],
                    prof.acceleration[: args.episode_ticks], None, 0)  # fmt: skip
    pool_loops = [ServoLoop(family.build(), PARAMS) for _ in range(args.workers)]
    for lp in pool_loops:
        lp.run(ep)

    def episodes(lp: ServoLoop, count: int) -> None:
        for _ in range(count):
            lp.run(ep)

    def run_d(workers: int):
        per = args.episodes // workers
        with ThreadPoolExecutor(workers) as ex:
            list(ex.map(episodes, pool_loops[:workers], [per] * workers))

    total = (args.episodes // args.workers) * args.workers * args.episode_ticks
    results["d_episodes_1_thread"] = rate(
        args.episodes * args.episode_ticks, timed(lambda: run_d(1), args.repeats)
    )
    results[f"d_episodes_{args.workers}_threads"] = rate(
        total, timed(lambda: run_d(args.workers), args.repeats)
    )

    med = {k: v["median"] for k, v in results.items()}
    ratios = {
        "b/a": med["b_closed_loop"] / med["a_bare_mj_step"],
        "b/c": med["b_closed_loop"] / med["c_python_loop"],
        "b/c2": med["b_closed_loop"] / med["c2_python_loop_compiled_filter"],
        "d_scaling": med[f"d_episodes_{args.workers}_threads"] / med["d_episodes_1_thread"],
    }
    cpu = platform.processor() or platform.machine()
    print(f"plant {args.plant}, chip {PARAMS.model} at {PARAMS.sample_time_us} us, "
          f"{args.repeats} repeats, {args.workers} workers, {cpu}")  # fmt: skip
    print(f"{'measurement':38s} {'ticks/s (median)':>18s} {'min .. max':>24s}")
    for k, v in results.items():
        print(f"{k:38s} {v['median']:18,.0f} {v['min']:11,.0f} .. {v['max']:<11,.0f}")
    targets = {"b/a": 0.85, "b/c": 1.5, "d_scaling": 1.6}
    for k, v in ratios.items():
        t = targets.get(k)
        verdict = "" if t is None else f"  (target >= {t}: {'met' if v >= t else 'NOT met'})"
        print(f"ratio {k:10s} {v:8.2f}{verdict}")
    if args.json_out:
        with open(args.json_out, "w") as f:
            json.dump({"args": vars(args), "results": results, "ratios": ratios}, f, indent=2)


if __name__ == "__main__":
    main()
