"""Speed of the closed servo loop, measured against baselines in the same run.

    .venv/bin/python experiments/bench_servo_loop.py [--plant rotary] [--repeats 7]

Prints ticks per second (median of the repeats, with min..max) for:
  (a) the accurate default closed loop (profile -> PMD filter -> amplifier with the chip's
      loop latency -> RK4 substeps -> encoder), one compiled call per episode
      (servogym.sim.ServoLoop with its defaults);
  (b) the old tick: the same loop with one implicitfast mj_step per tick and no latency
      (``integrator="euler"``, ``loop_latency="same_tick"``), what servogym ran before;
  (b2) plain RK4 per tick: the same loop recomputing every stage in full (what MuJoCo's own
      RK4 integrator does);
  (r) bare reference integrator steps on the same plant, no controller: a compiled loop of
      mj_step with MuJoCo's RK4 integrator, and (e) with its implicitfast integrator;
  (c) the default closed loop as a plain Python loop (servogym/sim/_pyloop.py);
  (d) many short episodes on all cores (threads; the compiled loop releases the GIL), against
      the same episodes on one thread;
and the ratios a/b (target >= 0.5), a/r, b2/b, a/c and d(all cores)/d(1 core) (target >= 1.8 on
2 cores). Results: docs/performance.md.
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

from servogym.chips.pmd import PMDAssumptions, PMDParams, move
from servogym.chips.pmd._reference import PMDReferenceFilter
from servogym.plants import get_plant
from servogym.sim import ServoLoop
from servogym.sim._ffi import mj_step
from servogym.sim._loop import INTEGRATORS
from servogym.sim._pyloop import python_closed_loop
from servogym.sim._runner import TRAVEL_MARGIN, current_loop_tau

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
    old_plant = family.build()
    old = ServoLoop(old_plant, PARAMS, PMDAssumptions(loop_latency="same_tick"),
                    integrator="euler", substeps=1)  # fmt: skip
    full_plant = family.build()
    full = ServoLoop(full_plant, PARAMS)
    full.full_stages = True  # every RK4 stage in full, as MuJoCo's RK4 integrator
    io = plant.io
    prof = profile_for(plant, args.ticks)
    n = prof.n_ticks
    bare = {}
    for name, integrator in (
        ("rk4", mujoco.mjtIntegrator.mjINT_RK4),
        ("implicitfast", mujoco.mjtIntegrator.mjINT_IMPLICITFAST),
    ):
        bp = family.build(timestep_s=PARAMS.sample_time_s)
        bp.model.opt.integrator = integrator
        bare[name] = bp

    # warm up every compiled function (and the numba cache)
    for bp in bare.values():
        bm, bd = bp.model, bp.data
        bare_steps(bm._address, bd._address, bd.qpos, bd.ctrl, io.qpos_adr, io.ctrl_index, 0.0, 10)
    for lp in (loop, old, full):
        lp.run(prof)

    def run_bare(bp):
        def run():
            bp.reset()
            bm, bd = bp.model, bp.data
            bare_steps(bm._address, bd._address, bd.qpos, bd.ctrl, io.qpos_adr, io.ctrl_index,
                       1e-3, n)  # fmt: skip

        return run

    def run_loop(lp):
        def run():
            r = lp.run(prof)
            assert r.metrics.n_ticks == n, r.metrics

        return run

    pn = min(args.python_ticks, n)
    short = type(prof)(prof.position[:pn], prof.velocity[:pn], prof.acceleration[:pn], None, 0)
    span = io.travel_max - io.travel_min
    bounds = (io.travel_min + TRAVEL_MARGIN * span, io.travel_max - TRAVEL_MARGIN * span)
    max_err = min(int(span * io.counts_per_unit), 2**31 - 1)
    m, d = plant.model, plant.data

    def run_c():
        plant.reset()
        origin = int(np.floor(d.qpos[io.qpos_adr] * io.counts_per_unit))
        r = python_closed_loop(m, d, io, INTEGRATORS["rk4"], loop.substeps, loop.full_stages,
                               loop.dt, loop.latency_s, current_loop_tau(io.current_bandwidth_hz),
                               *bounds, max_err, origin, PMDReferenceFilter(PARAMS),
                               short.position, short.velocity, short.acceleration)  # fmt: skip
        assert r[0] == pn

    results = {
        "a_accurate_default": rate(n, timed(run_loop(loop), args.repeats)),
        "b_old_tick": rate(n, timed(run_loop(old), args.repeats)),
        "b2_rk4_full_stages": rate(n, timed(run_loop(full), args.repeats)),
        "r_bare_mj_step_rk4": rate(n, timed(run_bare(bare["rk4"]), args.repeats)),
        "e_bare_mj_step_implicitfast": rate(n, timed(run_bare(bare["implicitfast"]), args.repeats)),
        "c_python_loop": rate(pn, timed(run_c, max(3, args.repeats // 2))),
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
        "a/b": med["a_accurate_default"] / med["b_old_tick"],
        "a/r": med["a_accurate_default"] / med["r_bare_mj_step_rk4"],
        "b2/b": med["b2_rk4_full_stages"] / med["b_old_tick"],
        "b/e": med["b_old_tick"] / med["e_bare_mj_step_implicitfast"],
        "a/c": med["a_accurate_default"] / med["c_python_loop"],
        "d_scaling": med[f"d_episodes_{args.workers}_threads"] / med["d_episodes_1_thread"],
    }
    cpu = platform.processor() or platform.machine()
    print(f"plant {args.plant}, chip {PARAMS.model} at {PARAMS.sample_time_us} us "
          f"({loop.substeps} RK4 substep(s), latency {loop.latency_s * 1e6:g} us), "
          f"{args.repeats} repeats, {args.workers} workers, {cpu}")  # fmt: skip
    print(f"{'measurement':38s} {'ticks/s (median)':>18s} {'min .. max':>24s}")
    for k, v in results.items():
        print(f"{k:38s} {v['median']:18,.0f} {v['min']:11,.0f} .. {v['max']:<11,.0f}")
    targets = {"a/b": 0.5, "d_scaling": 1.8}
    for k, v in ratios.items():
        t = targets.get(k)
        verdict = "" if t is None else f"  (target >= {t}: {'met' if v >= t else 'NOT met'})"
        print(f"ratio {k:10s} {v:8.2f}{verdict}")
    if args.json_out:
        with open(args.json_out, "w") as f:
            json.dump({"args": vars(args), "results": results, "ratios": ratios}, f, indent=2)


if __name__ == "__main__":
    main()
