"""Does the notch stage help? PID+FF tuning against PID+FF+notch tuning on a two-mass plant.

Issue 6 asks: on the two-mass plant with its first resonance inside the loop bandwidth, does
tuning with the PMAC notch stage (Ixx36..Ixx39) available reach a lower cost than PID-only
tuning at the same budget?

Set-up (see experiments/notch_two_mass.md for the discussion):

* Chip: TurboPMAC2 (442.7 us filter period), assumptions at their defaults.
* Plant: ``two-mass`` with ``stiffness_nm_per_rad = 2.25`` (nominal 9) and
  ``shaft_damping_nms = 1.5e-4`` (nominal 5e-4), everything else nominal: the first
  resonance moves from 100.7 Hz to 50.3 Hz (antiresonance 25.2 Hz, load inertia 3x the
  rotor's) with a modal damping ratio of about 0.01. Moves: the family's defaults (pi rad out
  and back, 30 rad/s, 1500 rad/s^2). Encoder on the motor shaft, so the cost sees the motor.
* Arms, same budget, same seeds, same sampler:

  - ``pid``: Ixx30, Ixx31, Ixx32, Ixx33, Ixx35, Ixx68 searched; Ixx36..Ixx39 fixed at 0.
  - ``pid+notch``: the same, plus a notch in physical units through
    :func:`servogym.chips.pmac.design_notch` (backward difference, poles at the zeros'
    frequency): notch frequency log-uniform in 15..400 Hz, zero damping log-uniform in
    0.005..0.5, pole damping uniform in 0.1..0.95. Ixx30 is rescaled by ``1/F(1)`` so the
    searched Ixx30 keeps its meaning (the DC loop gain), and the filter is always stable
    and well formed. This is a :class:`servogym.autotune.SearchSpace` subclass, so
    ``run_study`` and the TPE/CMA-ES tuners run unchanged.
  - ``pid+raw-notch`` (optional, ``--raw-arm``): Ixx36..Ixx39 searched directly as
    registers (linear over -2..2), the default search space of the chip.

* Every run: ``run_study`` with ``storage=None``, one evaluation thread, batch size 8;
  runs are spread over ``--processes`` worker processes.

Reproduce (the numbers in experiments/results/notch_two_mass/):

    .venv/bin/python experiments/notch_two_mass.py
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import multiprocessing as mp
import platform
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from servogym.autotune import SearchSpace, TuneProblem, run_study
from servogym.autotune._session import is_feasible, scored_trials
from servogym.chips.pmac import design_notch
from servogym.sim import Evaluator, Scenario

CHIP = "TurboPMAC2"
PLANT = "two-mass"
PLANT_VALUES = {"stiffness_nm_per_rad": 2.25, "shaft_damping_nms": 1.5e-4}
PID_FF = (
    "proportional_gain",
    "derivative_gain",
    "velocity_ff",
    "integral_gain",
    "acceleration_ff",
    "friction_ff",
)
NOTCH = ("notch_n1", "notch_n2", "notch_d1", "notch_d2")
OUT = Path(__file__).resolve().parent / "results" / "notch_two_mass"


def _log_lerp(u: float, lo: float, hi: float) -> float:
    return math.exp(math.log(lo) + (u + 1.0) / 2.0 * (math.log(hi) - math.log(lo)))


def _lin_lerp(u: float, lo: float, hi: float) -> float:
    return lo + (u + 1.0) / 2.0 * (hi - lo)


@dataclasses.dataclass(frozen=True)
class PhysicalNotchSpace(SearchSpace):
    """PMAC registers plus a notch searched in physical units (three extra unit params).

    ``u_notch_hz`` (log-uniform in ``notch_hz``), ``u_notch_zeta_zero`` (log-uniform in
    ``zeta_zero``) and ``u_notch_zeta_pole`` (uniform in ``zeta_pole``) become Ixx36..Ixx39
    through ``design_notch``; Ixx30 is rescaled by ``1/F(1)`` and clamped to its range.
    """

    notch_hz: tuple[float, float] = (15.0, 400.0)
    zeta_zero: tuple[float, float] = (0.005, 0.5)
    zeta_pole: tuple[float, float] = (0.1, 0.95)

    PHYSICAL = ("u_notch_hz", "u_notch_zeta_zero", "u_notch_zeta_pole")

    @property
    def unit_names(self) -> tuple[str, ...]:
        return super().unit_names + self.PHYSICAL

    def distributions(self) -> dict[str, Any]:
        from optuna.distributions import FloatDistribution

        out = super().distributions()
        out.update({u: FloatDistribution(-1.0, 1.0) for u in self.PHYSICAL})
        return out

    def physical(self, unit: Mapping[str, float]) -> dict[str, float]:
        """Notch frequency (Hz), zero and pole damping of a point of the unit cube."""
        return {
            "notch_hz": _log_lerp(float(unit["u_notch_hz"]), *self.notch_hz),
            "zeta_zero": _log_lerp(float(unit["u_notch_zeta_zero"]), *self.zeta_zero),
            "zeta_pole": _lin_lerp(float(unit["u_notch_zeta_pole"]), *self.zeta_pole),
        }

    def values_from_unit(self, unit: Mapping[str, float]) -> dict[str, int]:
        out = super().values_from_unit(unit)
        ph = self.physical(unit)
        ts = self.make_params({}).sample_time_s
        design = design_notch(
            ph["notch_hz"], ts, zero_damping=ph["zeta_zero"], pole_damping=ph["zeta_pole"]
        )
        out.update({n: getattr(design, n) for n in NOTCH})
        spec = self.family.parameter_space(self.chip_model)["proportional_gain"]
        gain = round(out["proportional_gain"] / float(design.dc_gain))
        out["proportional_gain"] = int(min(spec.high, max(spec.low, gain)))
        return out

    def to_unit(self, values: Mapping[str, Any]) -> dict[str, float]:
        # Only a warm start uses this: the notch starts at the centre of its box.
        return {**super().to_unit(values), **dict.fromkeys(self.PHYSICAL, 0.0)}

    def describe(self) -> dict[str, Any]:
        return {
            **super().describe(),
            "physical_notch": {
                "notch_hz": [*self.notch_hz, "log"],
                "zeta_zero": [*self.zeta_zero, "log"],
                "zeta_pole": [*self.zeta_pole, "linear"],
                "pole_hz": "= notch_hz",
                "proportional_gain": "searched value / F(1) (DC gain kept)",
            },
        }


def scenario() -> Scenario:
    return Scenario(CHIP, PLANT, plant_values=PLANT_VALUES)


def space_for(arm: str, ixx11: int) -> SearchSpace:
    """The arm's search space; Ixx11 (fatal following error limit, 1/16 count) fixed."""
    zeros = {**dict.fromkeys(NOTCH, 0), "fatal_following_error_limit": ixx11}
    if arm == "pid":
        return SearchSpace.for_chip(CHIP, PID_FF, zeros)
    if arm == "pid+notch":
        base = SearchSpace.for_chip(CHIP, PID_FF, zeros)
        return PhysicalNotchSpace(base.chip_model, base.names, base.fixed)
    if arm == "pid+raw-notch":
        return SearchSpace.for_chip(CHIP, PID_FF + NOTCH, {"fatal_following_error_limit": ixx11})
    raise ValueError(f"arm must be pid, pid+notch or pid+raw-notch; got {arm=}")


def run_one(job: tuple[str, str, int, int, int]) -> dict[str, Any]:
    """One study; returns JSON-ready per-trial data."""
    arm, tuner, seed, budget, ixx11 = job
    space = space_for(arm, ixx11)
    problem = TuneProblem(scenario=scenario(), space=space, seed=seed)
    t0 = time.perf_counter()
    result = run_study(problem, tuner, budget, storage=None, n_workers=1)
    elapsed = time.perf_counter() - t0
    trials = []
    for t in scored_trials(result.trials):
        out = t.user_attrs["outcome"]
        trials.append(
            {
                "number": t.number,
                "cost": float(t.values[0]),
                "feasible": bool(is_feasible(t)),
                "diverged": int(out["n_diverged"]) > 0,
            }
        )
    best = result.best
    rec = {
        "arm": arm,
        "tuner": tuner,
        "seed": seed,
        "budget": budget,
        "ixx11": ixx11,
        "elapsed_s": elapsed,
        "best_cost": float(best.values[0]),
        "best_feasible": bool(result.feasible),
        "best_number": best.number,
        "best_registers": result.best_values,
        "best_unit": dict(best.params),
        "trials": trials,
    }
    if isinstance(space, PhysicalNotchSpace):
        rec["best_notch"] = space.physical(best.params)
    return rec


# ------------------------------------------------------------------------------ analysis


def plant_matrices(values: Mapping[str, float], dt: float) -> tuple[np.ndarray, ...]:
    """The two-mass plant as the simulation steps it, linear: ``s' = A s + B u, y = C s``.

    State ``s = (q1, q2, v1, v2)``: rotor angle, shaft twist (MuJoCo's two hinges) and their
    rates; ``u`` the command (DAC bits), ``y`` the encoder (counts, unquantized). One tick is
    one MuJoCo step of ``dt`` with the implicit-in-velocity Euler step of ``implicitfast``:
    ``(M + dt D) v' = M v + dt (B tau - K q - D v)`` then ``q' = q + dt v'``. Coulomb friction,
    the travel limits and the encoder's quantization are left out. The command of tick k is
    computed from the encoder of tick k and acts during the step that follows.
    """
    j1, j2 = values["rotor_inertia_kgm2"], values["load_inertia_kgm2"]
    mass = np.array([[j1 + j2, j2], [j2, j2]])
    stiff = np.diag([0.0, values["stiffness_nm_per_rad"]])
    damp = np.diag([values["viscous_friction_nms"], values["shaft_damping_nms"]])
    torque_per_bit = values["torque_constant_nm_per_a"] * values["peak_current_a"] / 32768.0
    mi = np.linalg.inv(mass + dt * damp)
    eye = np.eye(2)
    vv = eye - dt * mi @ damp
    vq = -dt * mi @ stiff
    vu = dt * mi @ np.array([torque_per_bit, 0.0])
    a = np.block([[eye + dt * vq, dt * vv], [vq, vv]])
    b = np.concatenate([dt * vu, vu])[:, None]
    c = np.array([[values["encoder_counts_per_rev"] / (2 * np.pi), 0.0, 0.0, 0.0]])
    return a, b, c


def controller_tf(params: Any) -> tuple[np.ndarray, np.ndarray]:
    """PMAC's linear filter (error -> DAC bits) as polynomials in z^-1 (docs/chips/pmac.md 6).

    ``C(z) = 2^-19 Ixx30 F(z) [Ixx08 (1 + Ixx33 2^-23 z^-1/(1 - z^-1)) + Ixx31 Ixx09 2^-7
    (1 - z^-1)]``, the integrator only when Ixx63 > 0 (at rest: Ixx34 = 1 integrates then).
    """
    from servogym.chips.pmac import coefficient_value

    k = params.proportional_gain / 2**19
    i08, i09 = params.position_loop_scale, params.velocity_loop_scale
    gi = params.integral_gain / 2**23 if params.integration_limit > 0 else 0.0
    gd = params.derivative_gain * i09 / 128
    n1, n2, d1, d2 = (
        float(coefficient_value(getattr(params, f"notch_{x}"))) for x in ("n1", "n2", "d1", "d2")
    )
    fn, fd = np.array([1.0, n1, n2]), np.array([1.0, d1, d2])
    one_minus = np.array([1.0, -1.0])
    inner = i08 * np.pad(one_minus, (0, 1)) + i08 * gi * np.array([0.0, 1.0, 0.0])
    inner = inner + gd * np.convolve(one_minus, one_minus)
    num = k * np.convolve(fn, inner)
    den = np.convolve(fd, np.pad(one_minus, (0, 1)))
    return num, den


def loop_figures(registers: Mapping[str, int]) -> dict[str, float]:
    """Linear figures of the tuned loop on the simulated plant (no friction, no quantization).

    Returns the gain crossover (the highest frequency where ``|L|`` falls through 1), the
    phase margin there, ``|L|`` at the antiresonance and resonance, and the largest
    closed-loop pole magnitude (< 1: linearly stable).
    """
    from scipy import signal

    sc = scenario()
    params = sc.params(dict(registers))
    values = sc.draw_plant(np.random.default_rng(0))
    dt = params.sample_time_s
    a, b, c = plant_matrices(values, dt)
    num, den = controller_tf(params)
    f = np.geomspace(1.0, 0.5 / dt, 6000)
    z = np.exp(2j * np.pi * f * dt)
    plant = np.array([(c @ np.linalg.solve(zi * np.eye(4) - a, b))[0, 0] for zi in z])
    zinv = 1 / z
    ctrl = np.polyval(num[::-1], zinv) / np.polyval(den[::-1], zinv)
    loop = ctrl * plant
    mag = np.abs(loop)
    out: dict[str, float] = {"crossover_hz": float("nan"), "phase_margin_deg": float("nan")}
    high = np.flatnonzero(mag >= 1.0)
    if high.size and high[-1] + 1 < f.size:
        i = int(high[-1]) + 1
        out["crossover_hz"] = float(f[i])
        pm = 180.0 + float(np.degrees(np.angle(loop[i])))
        out["phase_margin_deg"] = (pm + 180.0) % 360.0 - 180.0
    res = resonances()
    for key in ("resonance_hz", "antiresonance_hz"):
        i = int(np.argmin(np.abs(f - res[key])))
        out[f"loop_gain_at_{key[:-3]}_db"] = float(20 * np.log10(mag[i]))
    # Closed loop: u = C(z) e, e = -y.
    ac, bc, cc, dc = signal.tf2ss(num, den)
    top = np.hstack([a - b @ (dc * c), b @ cc])
    bottom = np.hstack([-bc @ c, ac])
    poles = np.linalg.eigvals(np.vstack([top, bottom]))
    # A pole at exactly z = 1 is the integrator cancelled by a (1 - z^-1) factor of the
    # numerator when Ixx33 = 0 (not observable); leave it out.
    poles = poles[np.abs(poles - 1.0) > 1e-9]
    out["max_pole_radius"] = float(np.abs(poles).max())
    return out


def resonances() -> dict[str, float]:
    from servogym.plants import get_plant

    fam = get_plant(PLANT)
    v = scenario().draw_plant(np.random.default_rng(0))
    jeq = (
        v["rotor_inertia_kgm2"]
        * v["load_inertia_kgm2"]
        / (v["rotor_inertia_kgm2"] + v["load_inertia_kgm2"])
    )
    return {
        "resonance_hz": float(type(fam).resonance_hz(v)),
        "antiresonance_hz": float(
            math.sqrt(v["stiffness_nm_per_rad"] / v["load_inertia_kgm2"]) / (2 * math.pi)
        ),
        "modal_damping": float(
            v["shaft_damping_nms"] / (2 * math.sqrt(v["stiffness_nm_per_rad"] * jeq))
        ),
    }


def best_so_far(trials: list[dict[str, Any]], budget: int) -> np.ndarray:
    """Best feasible cost after each trial (NaN before the first feasible one)."""
    curve = np.full(budget, np.nan)
    best = math.inf
    by_number = {t["number"]: t for t in trials}
    for n in range(budget):
        t = by_number.get(n)
        if t is not None and t["feasible"]:
            best = min(best, t["cost"])
        curve[n] = best if math.isfinite(best) else np.nan
    return curve


def _fmt(x: float) -> str:
    return f"{x:.3f}"


def report(records: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    arms = list(dict.fromkeys(r["arm"] for r in records))
    tuners = list(dict.fromkeys(r["tuner"] for r in records))
    budget = meta["budget"]
    lines = [
        "# Notch vs PID-only tuning on the two-mass plant (TurboPMAC2)",
        "",
        f"Generated by `{meta['command']}` on {meta['date']} ({meta['wall_s']:.0f} s wall, "
        f"{meta['processes']} processes, {meta['machine']}).",
        "",
        f"Plant: two-mass, {PLANT_VALUES}; resonance {meta['plant']['resonance_hz']:.1f} Hz, "
        f"antiresonance {meta['plant']['antiresonance_hz']:.1f} Hz, modal damping "
        f"{meta['plant']['modal_damping']:.4f}. Budget {budget} evaluations per run; "
        f"seeds {meta['seeds']}. Ixx11 (fatal following error) fixed at {meta['ixx11']} "
        f"(1/16 count; 0 = no trip). Cost: docs/cost.md, the best *feasible* trial of each "
        "run.",
        "",
        "## Final cost per arm",
        "",
        "| tuner | arm | median | min | max | IQR | per seed | unsafe trials (diverged) "
        "| mean wall per run (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for tuner in tuners:
        for arm in arms:
            rs = [r for r in records if r["arm"] == arm and r["tuner"] == tuner]
            if not rs:
                continue
            rs.sort(key=lambda r: r["seed"])
            c = np.array([r["best_cost"] for r in rs])
            q1, q3 = np.percentile(c, [25, 75])
            per = ", ".join(
                f"{r['seed']}: {_fmt(r['best_cost'])}"
                + ("" if r["best_feasible"] else " (infeasible)")
                for r in rs
            )
            unsafe = sum(sum(not t["feasible"] for t in r["trials"]) for r in rs)
            div = sum(sum(t["diverged"] for t in r["trials"]) for r in rs)
            total = sum(len(r["trials"]) for r in rs)
            wall = np.mean([r["elapsed_s"] for r in rs])
            lines.append(
                f"| {tuner} | {arm} | {_fmt(np.median(c))} | {_fmt(c.min())} | {_fmt(c.max())} "
                f"| {_fmt(q3 - q1)} | {per} | {unsafe}/{total} ({div}) | {wall:.1f} |"
            )
    lines += ["", "## Paired differences (pid minus pid+notch, same seed)", ""]
    for tuner in tuners:
        a = {
            r["seed"]: r["best_cost"] for r in records if r["arm"] == "pid" and r["tuner"] == tuner
        }
        b = {
            r["seed"]: r["best_cost"]
            for r in records
            if r["arm"] == "pid+notch" and r["tuner"] == tuner
        }
        common = sorted(set(a) & set(b))
        if common:
            d = [a[s] - b[s] for s in common]
            wins = sum(x > 0 for x in d)
            lines.append(
                f"- {tuner}: differences {', '.join(_fmt(x) for x in d)}; median "
                f"{_fmt(float(np.median(d)))}; notch arm better on {wins}/{len(d)} seeds."
            )
    lines += ["", "## Best sets", ""]
    lines += [
        "Linear figures of each arm's best set on the simulated plant (its exact linear "
        "one-step map; Coulomb friction, limits and quantization left out): the gain "
        "crossover is the highest frequency where |L| falls through 1; the largest "
        "closed-loop pole radius is < 1 for a linearly stable loop.",
        "",
        "| tuner | arm | seed | cost | notch (Hz, zeta_z, zeta_p) | crossover (Hz) "
        "| phase margin (deg) | |L| at antiresonance (dB) | |L| at resonance (dB) "
        "| largest closed-loop pole radius |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key, fig in meta["loop"].items():
        tuner, arm, seed = key.split("|")
        r = next(
            r for r in records if r["tuner"] == tuner and r["arm"] == arm and str(r["seed"]) == seed
        )
        notch = r.get("best_notch")
        ns = (
            f"{notch['notch_hz']:.1f}, {notch['zeta_zero']:.3f}, {notch['zeta_pole']:.2f}"
            if notch
            else "-"
        )
        lines.append(
            f"| {tuner} | {arm} | {seed} | {_fmt(r['best_cost'])} | {ns} "
            f"| {fig['crossover_hz']:.1f} | {fig['phase_margin_deg']:.0f} "
            f"| {fig['loop_gain_at_antiresonance_db']:.1f} "
            f"| {fig['loop_gain_at_resonance_db']:.1f} | {fig['max_pole_radius']:.4f} |"
        )
    if meta.get("ablation"):
        lines += ["", "## Ablation: the best pid+notch sets with the notch removed", ""]
        lines += [
            "| tuner | seed | cost with notch | cost without (Ixx30 restored) |",
            "|---|---|---|---|",
        ]
        for row in meta["ablation"]:
            lines.append(
                f"| {row['tuner']} | {row['seed']} | {_fmt(row['with'])} | {_fmt(row['without'])} |"
            )
    lines += [
        "",
        "Files: `convergence.png` (median over seeds of the best feasible cost so far, a "
        "seed without a feasible trial yet counting as infinite; band = min..max over the "
        "seeds with one), `frequency_response.png` (the best pid+notch set: F(z) and C(z), "
        "plant resonance and antiresonance dashed), `results.json` (every trial).",
        "",
    ]
    return "\n".join(lines)


def plot_convergence(records: list[dict[str, Any]], budget: int, path: Path) -> None:
    from matplotlib.figure import Figure

    tuners = list(dict.fromkeys(r["tuner"] for r in records))
    arms = list(dict.fromkeys(r["arm"] for r in records))
    fig = Figure(figsize=(6.0 * len(tuners), 4.5), constrained_layout=True)
    axes = fig.subplots(1, len(tuners), squeeze=False)[0]
    x = np.arange(1, budget + 1)
    for ax, tuner in zip(axes, tuners, strict=True):
        for i, arm in enumerate(arms):
            curves = [
                best_so_far(r["trials"], budget)
                for r in records
                if r["arm"] == arm and r["tuner"] == tuner
            ]
            if not curves:
                continue
            # A run without a feasible trial yet counts as +inf: the median is drawn once
            # most seeds have one, the band (min .. max) where any has.
            arr = np.nan_to_num(np.vstack(curves), nan=np.inf)
            med = np.median(arr, axis=0)
            med[~np.isfinite(med)] = np.nan
            lo = np.where(np.isfinite(arr.min(axis=0)), arr.min(axis=0), np.nan)
            hi = np.where(np.isfinite(arr.max(axis=0)), arr.max(axis=0), np.nan)
            ax.plot(x, med, color=f"C{i}", label=f"{arm} (median of {len(curves)})")
            ax.fill_between(x, lo, hi, color=f"C{i}", alpha=0.15)
        if any(np.isfinite(line.get_ydata()).any() for line in ax.get_lines()):
            ax.set_yscale("log")
        ax.set_xlabel("evaluations")
        ax.set_ylabel("best feasible cost so far")
        ax.set_title(f"{tuner}: TurboPMAC2, two-mass (resonance 50 Hz)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.savefig(path, dpi=100)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=int, default=400)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--tuners", default="tpe,cmaes")
    ap.add_argument("--raw-arm", action="store_true", help="also search Ixx36..39 directly")
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument(
        "--ixx11",
        default="32000,0",
        help="fatal following error limits (1/16 count) to run, one result folder each; "
        "32000 is the chip default (2000 counts), 0 disables the trip",
    )
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument(
        "--reanalyse", action="store_true", help="redo tables and plots from results.json"
    )
    args = ap.parse_args(argv)
    root = args.out
    for ixx11 in (int(x) for x in args.ixx11.split(",")):
        args.out = root / f"ixx11_{ixx11}"
        if args.reanalyse:
            data = json.loads((args.out / "results.json").read_text())
            analyse(data["runs"], data["meta"], args.out)
        else:
            run_variant(args, ixx11, argv)


def run_variant(args: argparse.Namespace, ixx11: int, argv: list[str] | None) -> None:
    """Every arm, tuner and seed at one Ixx11 setting; writes args.out."""
    arms = ["pid", "pid+notch"] + (["pid+raw-notch"] if args.raw_arm else [])
    tuners = args.tuners.split(",")
    seeds = list(range(args.seeds))
    jobs = [(a, t, s, args.budget, ixx11) for t in tuners for s in seeds for a in arms]
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    records = []
    ctx = mp.get_context("fork")
    with ctx.Pool(args.processes) as pool:
        for rec in pool.imap_unordered(run_one, jobs):
            records.append(rec)
            print(
                f"[{time.perf_counter() - t0:7.1f} s] {rec['tuner']:6s} {rec['arm']:14s} "
                f"seed {rec['seed']}: best {rec['best_cost']:.4f} "
                f"({'feasible' if rec['best_feasible'] else 'INFEASIBLE'}) in "
                f"{rec['elapsed_s']:.1f} s",
                flush=True,
            )
    wall = time.perf_counter() - t0
    records.sort(key=lambda r: (tuners.index(r["tuner"]), arms.index(r["arm"]), r["seed"]))
    run = {
        "command": "python experiments/notch_two_mass.py "
        + " ".join(sys.argv[1:] if argv is None else argv),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "wall_s": wall,
        "processes": args.processes,
        "machine": f"{platform.machine()}, Python {platform.python_version()}",
        "budget": args.budget,
        "seeds": seeds,
        "ixx11": ixx11,
    }
    # The raw data first, so that a failing analysis loses nothing (--reanalyse).
    (args.out / "results.json").write_text(
        json.dumps({"meta": run, "runs": records}, separators=(",", ":"))
    )
    analyse(records, run, args.out)


def analyse(records: list[dict[str, Any]], run: dict[str, Any], out: Path) -> None:
    """Tables, loop figures, ablation and plots of one Ixx11 setting; writes ``out``."""
    from servogym.chips.pmac import plot_frequency_response

    tuners = list(dict.fromkeys(r["tuner"] for r in records))
    arms = list(dict.fromkeys(r["arm"] for r in records))
    ixx11 = run["ixx11"]
    # Loop figures of each arm's best set (per tuner), and the notch ablation.
    loop, ablation = {}, []
    ev = Evaluator(scenario())
    for tuner in tuners:
        for arm in arms:
            rs = [r for r in records if r["arm"] == arm and r["tuner"] == tuner]
            b = min(rs, key=lambda r: (not r["best_feasible"], r["best_cost"]))
            loop[f"{tuner}|{arm}|{b['seed']}"] = loop_figures(b["best_registers"])
        for r in records:
            if r["arm"] != "pid+notch" or r["tuner"] != tuner:
                continue
            regs = dict(r["best_registers"])
            unit = r["best_unit"]
            plain = space_for("pid", ixx11).values_from_unit(unit)
            without = {
                **regs,
                **dict.fromkeys(NOTCH, 0),
                "proportional_gain": plain["proportional_gain"],
            }
            sc = scenario()
            if not r["best_feasible"]:
                continue
            ablation.append(
                {
                    "tuner": tuner,
                    "seed": r["seed"],
                    "with": ev.evaluate(sc.params(regs)).cost,
                    "without": ev.evaluate(sc.params(without)).cost,
                }
            )
    plant = resonances()
    best_b = min(
        (r for r in records if r["arm"] == "pid+notch"),
        key=lambda r: (not r["best_feasible"], r["best_cost"]),
    )
    meta = {**run, "plant": plant, "loop": loop, "ablation": ablation}
    (out / "results.json").write_text(
        json.dumps({"meta": meta, "runs": records}, separators=(",", ":"))
    )
    text = report(records, meta)
    (out / "results.md").write_text(text)
    params = scenario().params(best_b["best_registers"])
    n = best_b["best_notch"]
    plot_frequency_response(
        params,
        out / "frequency_response.png",
        mark_hz=[plant["antiresonance_hz"], plant["resonance_hz"]],
        title=(
            f"best pid+notch set ({best_b['tuner']}, seed {best_b['seed']}): notch "
            f"{n['notch_hz']:.1f} Hz, zeta_z {n['zeta_zero']:.3f}, zeta_p {n['zeta_pole']:.2f}\n"
            f"dashed: plant antiresonance {plant['antiresonance_hz']:.1f} Hz, "
            f"resonance {plant['resonance_hz']:.1f} Hz"
        ),
    )
    plot_convergence(records, run["budget"], out / "convergence.png")
    print(text)


if __name__ == "__main__":
    main()
