"""Speed of the N-axis closed loop, measured against baselines in the same run.

    .venv/bin/python experiments/bench_multiaxis.py [--chip TurboPMAC2] [--repeats 7]

Prints ticks per second (median of the repeats, with min..max) for:
  (m2) a 2-axis episode: two axes of one controller around a two-axis plant, one compiled
       call (servogym.sim.MultiServoLoop with its defaults);
  (s1) a 1-axis episode of the comparable single-axis plant (servogym.sim.ServoLoop), and
  (s2) two such episodes one after the other (what running the two axes separately costs);
  (m1) the same 1-axis plant as a 1-axis machine through the N-axis loop (its own overhead);
  (r2) bare steps of the same two-axis model, no controller: a compiled loop of mj_step
       with MuJoCo's RK4 integrator at the servo period;
and the ratios: cost of one 2-axis tick / one 1-axis tick (goal <= 1.5), 2-axis episode /
two 1-axis episodes, m1/s1 (the N-axis loop's overhead on one axis) and m2/r2. Every figure
comes from this run; the servo period (and so the substeps per tick) is the same for the
1- and 2-axis loops. The pairs: two-link-arm (vertical) against arm, xy-stage against
vertical-axis.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from types import SimpleNamespace

import mujoco
import numpy as np
from numba import njit

from servogym.chips import all_models
from servogym.plants import MULTI_PLANTS, get_plant
from servogym.sim import MultiServoLoop, ServoLoop, machine_params
from servogym.sim._ffi import mj_step

GAINS = {
    "pmd": {"kp": 40, "kd": 400, "ki": 10, "derivative_time": 1, "kout": 8000},
    "pmac": {"proportional_gain": 20000, "derivative_gain": 3000, "fatal_following_error_limit": 0},
    "parker6k": {},
}

PAIRS = (("two-link-arm", {"vertical": 1}, "arm"), ("xy-stage", {}, "vertical-axis"))


@njit(cache=True, nogil=True)
def bare_steps(m_addr, d_addr, qpos, ctrl, n_axes, torque, n):
    """(r2): read every joint, write a constant torque to every actuator, mj_step; n times."""
    s = 0.0
    for _ in range(n):
        for i in range(n_axes):
            s += qpos[i]
            ctrl[i] = torque
        mj_step(m_addr, d_addr)
    return s


def back_and_forth(io, n_ticks: int, fraction: float = 0.01) -> SimpleNamespace:
    """A sine of ``fraction`` of the travel, 10 periods over the episode (counts)."""
    amp = fraction * (io.travel_max - io.travel_min) * io.counts_per_unit
    t = np.arange(n_ticks)
    pos = np.round(amp * np.sin(2 * np.pi * 10 * t / n_ticks)).astype(np.int64)
    zeros = np.zeros(n_ticks, np.int64)
    return SimpleNamespace(position=pos, velocity=zeros, acceleration=zeros.copy(), start=0)


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


def bench_pair(multi_name, values, single_name, chip_model, n, repeats) -> dict:
    chip = all_models()[chip_model]
    gains = GAINS[chip.name]
    multi_plant = MULTI_PLANTS[multi_name].build(values)
    n_axes = len(multi_plant.ios)
    params2 = machine_params(chip_model, n_axes, gains)
    # the same period for the 1-axis loops (a PMD chip's is n_axes slots for n_axes axes)
    params1 = params2[:1]
    m2 = MultiServoLoop(multi_plant, params2)
    single = get_plant(single_name).build()
    s1 = ServoLoop(single, params1[0])
    m1 = MultiServoLoop(get_plant(single_name).build(), params1)
    assert s1.dt == m2.dt and s1.substeps == m2.substeps, (s1.dt, m2.dt)
    prof2 = [back_and_forth(io, n) for io in multi_plant.ios]
    prof1 = back_and_forth(single.io, n)
    bare = MULTI_PLANTS[multi_name].build(values, timestep_s=m2.dt)
    bare.model.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    bm, bd = bare.model, bare.data

    def run_m2():
        r = m2.run(prof2)
        assert r.axis == -1 and r.metrics[0].n_ticks == n, r.metrics

    def run_s1():
        r = s1.run(prof1)
        assert r.metrics.n_ticks == n, r.metrics

    def run_s2():
        run_s1()
        run_s1()

    def run_m1():
        r = m1.run([prof1])
        assert r.metrics[0].n_ticks == n, r.metrics

    def run_r2():
        bare.reset()
        bare_steps(bm._address, bd._address, bd.qpos, bd.ctrl, n_axes, 1e-3, n)

    for fn in (run_m2, run_s1, run_m1, run_r2):
        fn()  # warm up (compile or load the numba cache)
    res = {
        "m2_two_axis_episode": rate(n, timed(run_m2, repeats)),
        "s1_one_axis_episode": rate(n, timed(run_s1, repeats)),
        "s2_two_one_axis_episodes": rate(n, timed(run_s2, repeats)),
        "m1_one_axis_machine": rate(n, timed(run_m1, repeats)),
        "r2_bare_mj_step_rk4": rate(n, timed(run_r2, repeats)),
    }
    med = {k: v["median"] for k, v in res.items()}
    ratios = {
        "tick_cost_2axis/1axis": med["s1_one_axis_episode"] / med["m2_two_axis_episode"],
        "episode_2axis/two_1axis": med["s2_two_one_axis_episodes"] / med["m2_two_axis_episode"],
        "m1/s1_cost": med["s1_one_axis_episode"] / med["m1_one_axis_machine"],
        "m2/r2_cost": med["r2_bare_mj_step_rk4"] / med["m2_two_axis_episode"],
    }
    head = (f"{multi_name} ({', '.join(multi_plant.family.axes)}) vs {single_name}, "
            f"{chip_model} at {m2.dt * 1e6:.1f} us ({m2.substeps} RK4 substeps, latencies "
            f"{', '.join(f'{x * 1e6:.1f}' for x in m2.latencies_s)} us)")  # fmt: skip
    return {"pair": head, "results": res, "ratios": ratios}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--chip", default="TurboPMAC2", help="chip model (any family)")
    ap.add_argument("--ticks", type=int, default=20_000, help="ticks per timed episode")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--json", dest="json_out", help="also write the results here")
    args = ap.parse_args()
    out = []
    cpu = platform.processor() or platform.machine()
    print(f"{args.repeats} repeats of {args.ticks} ticks, {cpu}")
    for multi_name, values, single_name in PAIRS:
        r = bench_pair(multi_name, values, single_name, args.chip, args.ticks, args.repeats)
        out.append(r)
        print(r["pair"])
        print(f"  {'measurement':30s} {'ticks/s (median)':>18s} {'min .. max':>24s}")
        for k, v in r["results"].items():
            print(f"  {k:30s} {v['median']:18,.0f} {v['min']:11,.0f} .. {v['max']:<11,.0f}")
        for k, v in r["ratios"].items():
            goal = ""
            if k == "tick_cost_2axis/1axis":
                goal = f"  (goal <= 1.5: {'met' if v <= 1.5 else 'NOT met'})"
            print(f"  ratio {k:26s} {v:8.2f}{goal}")
    if args.json_out:
        with open(args.json_out, "w") as f:
            json.dump({"args": vars(args), "pairs": out}, f, indent=2)


if __name__ == "__main__":
    main()
