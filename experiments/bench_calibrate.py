"""How long `servogym calibrate` takes, and what it recovers, on synthetic traces.

    .venv/bin/python experiments/bench_calibrate.py [--repeats 3] [--cases rotary,pmac]
        [--write-trace runs/trace.csv]

Each case is a trace servogym makes (servogym.calibrate.synthetic_trace: the reference RK4 x
32 integration, the encoder's quantisation, 2 counts of Gaussian noise on the recorded motor
command) of a plant with hidden values at a latency that is not the chip's default; the fit
(latency included, every candidate) runs ``--repeats`` times and the median wall time is
printed, with the replays run, the recovered values' errors, the latency found and the
closed-loop replay's RMS error. Results: docs/calibrate.md ("Speed and accuracy"); the
JSON lines go to experiments/results/bench_calibrate.jsonl.

``--write-trace PATH`` writes the rotary case's trace as a CSV, and its register set
beside it (``PATH`` with ``.json``), for the README tour, and exits.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

from servogym.calibrate import calibrate, read_trace, synthetic_trace, to_csv
from servogym.chips import read_params_file
from servogym.chips.pmd import PMDParams, to_json
from servogym.sim import MoveSpec

PMD = PMDParams(model="MC2100", kp=60, kd=600, ki=20, kout=6000, derivative_time=1)
ROTARY_MOVES = (MoveSpec(1.0, 40.0, 3000.0, 0.03), MoveSpec(-1.0, 40.0, 3000.0, 0.03))
DATA = Path(__file__).parents[1] / "tests" / "calibrate" / "data"

CASES = {
    # name: (plant, hidden values, latency, moves)
    "rotary": ("rotary", {"load_inertia_kgm2": 1.5e-4, "coulomb_friction_nm": 0.03},
               "half_period", ROTARY_MOVES),
    "vertical-axis": ("vertical-axis", {"payload_kg": 3.5, "coulomb_friction_n": 20.0,
                                        "viscous_friction_ns_per_m": 30.0}, "half_period", ()),
    "two-mass": ("two-mass", {"load_inertia_kgm2": 1.5e-4, "stiffness_nm_per_rad": 5.0,
                              "shaft_damping_nms": 1e-3, "coulomb_friction_nm": 0.03},
                 "half_period", ()),
    "arm": ("arm", {"payload_kg": 1.0, "coulomb_friction_nm": 0.2}, "half_period", ()),
}  # fmt: skip


def _case(name: str):
    """``(trace, params, plant, hidden, latency)`` of a case."""
    if name == "pmac":
        loaded = read_params_file(DATA / "pmac_rotary.pmc")
        trace = read_trace(DATA / "pmac_gather_rotary.txt", "pmac", params=loaded.params)
        hidden = {"load_inertia_kgm2": 1.5e-4, "coulomb_friction_nm": 0.03}
        return trace, loaded.params, "rotary", hidden, "full_period"
    plant, hidden, latency, moves = CASES[name]
    trace = synthetic_trace("MC2100", plant, hidden, params=PMD, loop_latency=latency,
                            moves=moves, command_noise_counts=2.0, seed=1)  # fmt: skip
    return trace, PMD, plant, hidden, latency


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cases", default="rotary,pmac,vertical-axis,two-mass,arm")
    ap.add_argument("--write-trace", type=Path, default=None)
    args = ap.parse_args()
    if args.write_trace is not None:
        trace, params, *_ = _case("rotary")
        args.write_trace.parent.mkdir(parents=True, exist_ok=True)
        args.write_trace.write_text(to_csv(trace, ("commanded_velocity", "commanded_acceleration")))
        args.write_trace.with_suffix(".json").write_text(to_json(params))
        print(f"wrote {args.write_trace} and {args.write_trace.with_suffix('.json')}")
        return
    out = Path(__file__).parent / "results" / "bench_calibrate.jsonl"
    out.parent.mkdir(exist_ok=True)
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
          f"median of {args.repeats} fits")  # fmt: skip
    for name in args.cases.split(","):
        trace, params, plant, hidden, latency = _case(name)
        times, cal = [], None
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            cal = calibrate(trace, params, plant)
            times.append(time.perf_counter() - t0)
        errors = {k: cal.plant[k] / v - 1.0 for k, v in hidden.items()}
        row = {
            "case": name, "chip": params.model, "plant": plant, "n_samples": trace.n_ticks,
            "fit_time_s_median": statistics.median(times), "fit_times_s": times,
            "replays": cal.n_evaluations, "latency_true": latency, "latency_found": cal.latency,
            "rms_error_counts": cal.rms_error_counts,
            "open_loop_rms_error_counts": cal.open_loop_rms_error_counts,
            "relative_errors": errors, "poor_fit": cal.poor,
        }  # fmt: skip
        with out.open("a") as fh:
            fh.write(json.dumps(row) + "\n")
        errs = ", ".join(f"{k} {100 * e:+.2g} %" for k, e in errors.items())
        print(
            f"{name:14s} {params.model:10s} {trace.n_ticks:5d} "
            f"samples: {statistics.median(times):6.2f} s ({cal.n_evaluations} replays); "
            f"latency {cal.latency} (true {latency}); replay RMS {cal.rms_error_counts:.3g} "
            f"counts; {errs}"
        )


if __name__ == "__main__":
    main()
