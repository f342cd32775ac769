"""Classical tuning procedures a motion engineer would recognise, run through the simulator.

Each runs *experiments* on the nominal plant through the chip's own filter (step responses,
relay oscillations, identification moves), designs a controller in physical units
(:class:`ServoDesign`), maps it into legal registers with the chip family's
:class:`GainMap`, and scores a few *candidates* on the scenario. Every experiment and every
candidate is one evaluation of the budget and one trial of the study; the best candidate
is the result. See docs/autotune.md for the procedures and their rules.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from servogym.autotune._gains import ServoDesign, design_registers, gain_map_for
from servogym.autotune._problem import Outcome
from servogym.autotune._session import Session, TuneError
from servogym.autotune._tuners import Tuner, register_tuner

FULL_SCALE = 32768.0
"""Motor command counts at 100 % (every chip's 16-bit output)."""


@dataclasses.dataclass(frozen=True)
class _Profile:
    """A chip-independent profile: positions per tick, no velocity or acceleration input."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    start: int

    @classmethod
    def setpoints(cls, levels: list[tuple[int, int]]) -> _Profile:
        """Hold each ``(position, n_ticks)`` in turn, starting from 0."""
        pos = np.concatenate([np.full(n, p, np.int64) for p, n in levels])
        zero = np.zeros_like(pos)
        return cls(pos, zero, zero, 0)


class _Context:
    """What every procedure needs: the chip, the plant's scale, the base registers."""

    def __init__(self, session: Session) -> None:
        self.session = session
        problem = session.problem
        self.space = problem.space
        self.family = self.space.family
        gain_map_for(self.family)  # fails early, with the extension point, for a new family
        self.base_values = {
            **self.family.parameter_space(self.space.chip_model).defaults(),
            **self.space.fixed,
        }
        self.base = self.space.make_params(self.base_values)
        self.dt = self.family.sample_time_s(self.base)
        self.assumptions = problem.scenario.assumptions
        ev = session.identification_evaluator
        cpu = ev.plant.io.counts_per_unit
        self.move_counts = max(abs(m.distance) for m in problem.scenario.moves) * cpu
        span = (ev.plant.io.travel_max - ev.plant.io.travel_min) * cpu
        self.move_counts = min(self.move_counts, 0.2 * span)

    def registers(self, design: ServoDesign, *, experiment: bool = False) -> dict[str, int]:
        """Registers for a design; a candidate keeps only the searched registers' values."""
        values = design_registers(design, self.base, self.base_values, self.assumptions)
        if experiment:
            # An experiment must not trip the chip's own error limit, if it has one.
            values.update(self.family.error_trip_off)
            return values
        kept = {n: values[n] for n in self.space.names}
        return {**self.base_values, **kept}

    def run(
        self, design: ServoDesign, profile: _Profile, note: str, measure: Any
    ) -> dict[str, Any]:
        """One experiment: run ``profile`` with ``design``; ``measure(traces)`` -> dict."""
        values = self.registers(design, experiment=True)

        def go(evaluator: Any) -> dict[str, Any]:
            params = self.space.make_params(values)
            result = evaluator.loop.run(profile, params=params, traces=True, reset=True)
            out = {"diverged": bool(result.metrics.diverged)}
            if not result.metrics.diverged:
                out.update(measure(result.traces))
            return out

        return self.session.experiment(values, note, go)

    def candidates(self, designs: list[tuple[ServoDesign, str]]) -> list[Outcome]:
        """Score designs on the scenario (as many as the budget holds)."""
        designs = designs[: max(self.session.remaining, 0)]
        if not designs:
            return []
        return self.session.candidates([(self.registers(d), note) for d, note in designs])


def _ticks(seconds: float, dt: float) -> int:
    return max(4, round(seconds / dt))


# ------------------------------------------------------------------------------------------
# Vendor step-response procedure
# ------------------------------------------------------------------------------------------


def _step_measure(traces: Any, step: int, half: int, limit: float) -> dict[str, Any]:
    """Overshoot, settling, steady-state error and holding command of an up-and-back step."""
    e = traces.error.astype(float)
    u = traces.command.astype(float)
    out: dict[str, Any] = {"overshoot": 0.0, "settle_s": 0.0, "sse": 0.0, "chatter": 0.0}
    holds = []
    for k, (lo, hi) in enumerate(((0, half), (half, len(e)))):
        seg_e = e[lo:hi] * (1 if k == 0 else -1)  # error in the move's direction
        seg_u = u[lo:hi]
        # Past the target, the error changes sign; its largest excursion is the overshoot.
        out["overshoot"] = max(out["overshoot"], float(max(0.0, -seg_e.min())) / step)
        band = max(4.0, 0.02 * step)
        outside = np.flatnonzero(np.abs(seg_e) > band)
        n_seg = hi - lo
        settle = (outside[-1] + 1) if outside.size else 0
        out["settle_s"] = max(out["settle_s"], settle * float(traces.time_s[1]))
        tail = max(1, n_seg // 5)
        out["sse"] = max(out["sse"], float(np.abs(seg_e[-tail:]).mean()))
        holds.append(float(seg_u[-tail:].mean()))
        out["chatter"] = max(out["chatter"], float(np.abs(np.diff(seg_u)).mean()) / FULL_SCALE)
        out["settled"] = bool(settle < n_seg)
    out["hold_up"], out["hold_down"] = holds
    out["saturation"] = float(np.mean(np.abs(u) >= limit))
    return out


@register_tuner
class VendorStepTuner(Tuner):
    """The step-response procedure of the vendors' tuning guides.

    On a small step up and back: raise Kp (doubling) until the response overshoots
    (slightly underdamped), raise Kd until it is damped, then alternately raise Kp and
    re-damp with Kd while the step settles faster and the command stays quiet; set the
    bias to the gravity holding command the steps measured, raise Ki (with an integration
    limit) until the steady-state error is gone; finally run the scenario's moves and set
    the velocity and acceleration feed-forward to the command the loop needed during them.
    """

    name = "vendor-step"
    min_budget = 8

    max_chatter = 0.01
    """Quietest acceptable step: mean command change per tick as a fraction of full scale."""

    def run(self, session: Session) -> None:
        session.evaluate_warm_start()
        ctx = _Context(session)
        reserve = 4  # the feed-forward experiment and three candidates
        step = int(min(max(50.0, 0.01 * ctx.move_counts), 5000.0))
        half = _ticks(0.15, ctx.dt)
        profile = _Profile.setpoints([(step, half), (0, half)])
        limit = float(ctx.family.motor_limit(ctx.base))

        def test(design: ServoDesign, note: str) -> dict[str, Any] | None:
            if session.remaining <= reserve:
                return None
            return ctx.run(design, profile, note, lambda tr: _step_measure(tr, step, half, limit))

        def quiet(r: dict[str, Any]) -> bool:
            return not r["diverged"] and r["chatter"] <= self.max_chatter

        # 1. Kp alone, doubling from 1 % of full scale for a full-step error.
        design = ServoDesign(p=0.01 * FULL_SCALE / step)
        last = None
        for _ in range(20):
            r = test(design, f"step: raise Kp (p={design.p:.4g})")
            if r is None or r["diverged"]:
                break
            last = r
            if r["overshoot"] >= 0.1:
                break
            design = design.replace(p=design.p * 2)
        if last is None:
            raise TuneError("vendor-step: the first step response diverged; no gain to start")
        # 2. Damp it: Kd doubling from a derivative time of two servo cycles.
        design = design.replace(d=design.p * 2 * ctx.dt)
        good: tuple[ServoDesign, dict[str, Any]] | None = None
        for _ in range(12):
            r = test(design, f"step: add damping (d={design.d:.4g})")
            if r is None or not quiet(r):
                break
            if r["overshoot"] <= 0.05:
                good = (design, r)
                break
            design = design.replace(d=design.d * 2)
        if good is None:
            good = (design, r) if r is not None and quiet(r) else (design, last)
        # 3. Stiffen: Kp x2, re-damp (Kd x sqrt 2 per try), while settling improves.
        while session.remaining > reserve:
            best_design, best = good
            trial = best_design.replace(p=best_design.p * 2, d=best_design.d * math.sqrt(2))
            accepted = None
            for _ in range(3):
                r = test(trial, f"step: raise Kp, re-damp (p={trial.p:.4g}, d={trial.d:.4g})")
                if r is None or not quiet(r) or r["saturation"] > 0.05:
                    break
                if r["overshoot"] <= 0.05:
                    accepted = (trial, r)
                    break
                trial = trial.replace(d=trial.d * math.sqrt(2))
            if accepted is None or accepted[1]["settle_s"] > best["settle_s"]:
                break
            good = accepted
        design, r = good
        # 4. Bias for gravity (the mean holding command of the two directions), then Ki.
        bias = 0.5 * (r["hold_up"] + r["hold_down"])
        friction = 0.5 * abs(r["hold_up"] - r["hold_down"])
        design = design.replace(
            bias=bias,
            integral_limit=min(0.25 * FULL_SCALE, max(0.02 * FULL_SCALE, 3 * friction)),
        )
        td = design.d / design.p if design.p > 0 else ctx.dt
        ti = 40 * td
        with_i = design
        for _ in range(6):
            trial = design.replace(i=design.p / ti)
            r2 = test(trial, f"step: add integral (i={trial.i:.4g})")
            if r2 is None or not quiet(r2) or r2["overshoot"] > 0.15:
                break
            with_i = trial
            if r2["sse"] <= 1.0:
                break
            ti /= 2
        design = with_i
        # 5. Feed-forward: the command the loop needed during the moves, by least squares.
        ff = _feedforward_experiment(ctx, design)
        designs = [(design, "vendor-step: PID")]
        if ff is not None:
            designs.append((design.replace(vff=ff["vff"]), "vendor-step: PID + Kvff"))
            designs.append((design.replace(vff=ff["vff"], aff=ff["aff"]),
                            "vendor-step: PID + Kvff + Kaff"))  # fmt: skip
        ctx.candidates(designs)


def _feedforward_experiment(ctx: _Context, design: ServoDesign) -> dict[str, float] | None:
    """Run the scenario's moves with ``design``; fit command ~ c + vff*v + aff*a."""
    session = ctx.session
    if session.remaining < 2:
        return None
    values = ctx.registers(design, experiment=True)

    def go(evaluator: Any) -> dict[str, Any]:
        ev = evaluator.evaluate(ctx.space.make_params(values), traces=True)
        if ev.diverged:
            return {"diverged": True}
        cmd = np.concatenate([r.traces.commanded for r in ev.results]).astype(float)
        u = np.concatenate([r.traces.command for r in ev.results]).astype(float)
        v = np.gradient(cmd, ctx.dt)
        a = np.gradient(v, ctx.dt)
        x = np.column_stack([np.ones_like(v), v, a])
        coef, *_ = np.linalg.lstsq(x, u - design.bias, rcond=None)
        return {"diverged": False, "offset": coef[0], "vff": coef[1], "aff": coef[2]}

    r = session.experiment(values, "feed-forward: command during the moves", go)
    if r["diverged"]:
        return None
    return {"vff": max(0.0, r["vff"]), "aff": max(0.0, r["aff"])}


# ------------------------------------------------------------------------------------------
# Relay feedback with the Astrom-Hagglund phase-margin rule
# ------------------------------------------------------------------------------------------


def _relay_measure(traces: Any, dt: float) -> dict[str, Any]:
    """Period and first-harmonic response of a relay oscillation (second half of the run)."""
    u = traces.command.astype(float)
    x = traces.actual.astype(float)
    h = len(u) // 2
    centred = u[h:] - u[h:].mean()
    rising = np.flatnonzero((centred[:-1] <= 0) & (centred[1:] > 0))
    if len(rising) < 3:
        return {"oscillates": False}
    i0, i1 = int(rising[0]) + h, int(rising[-1]) + h
    period = (i1 - i0) / (len(rising) - 1) * dt
    w = 2 * math.pi / period
    t = np.arange(i0, i1) * dt
    xs = x[i0:i1] - np.polyval(np.polyfit(t, x[i0:i1], 1), t)  # drift removed
    basis = np.exp(-1j * w * t)
    g = np.sum(xs * basis) / np.sum(u[i0:i1] * basis)
    amplitude = float(np.ptp(xs) / 2)
    return {
        "oscillates": amplitude > 3.0,
        "period_s": period,
        "amplitude_counts": amplitude,
        "gain": float(abs(g)),
        "phase_deg": float(np.degrees(np.angle(g))),
        "mean_command": float(u[i0:i1].mean()),
    }


MAX_PID_LEAD_DEG = 80.0
"""Largest phase lead (degrees) the Astrom-Hagglund rule asks of the PID."""


def astrom_hagglund(
    w: float, gain: float, phase_deg: float, phase_margin_deg: float = 45.0, alpha: float = 4.0
) -> tuple[float, float, float]:
    """PID (p, i, d) putting the loop at ``w`` on the unit circle with a phase margin.

    Given one point of the plant's frequency response, ``G(jw) = gain * exp(j*phase)``,
    the rule of Astrom and Hagglund (PID Controllers, 1995, sec. 4.7): the controller
    ``p * (1 + 1/(Ti s) + Td s)`` with ``Ti = alpha * Td`` must add ``phase_margin - phi_b``
    of phase at ``w``, where ``G = gain * exp(j(pi + phi_b))``, and have gain ``1/|G|``.
    ``phi_b`` is clipped to [-60, 0] degrees (a rigid axis with a small delay), and further so
    that the lead stays at most :data:`MAX_PID_LEAD_DEG`: a PID adds less than 90 degrees,
    and at a lead of 90 or more the rule's ``cos(lead)`` would make every gain negative (a
    relay point lagged by the loop latency, issue 13). The loop then crosses at ``w`` with
    less than the margin; the relay tuner's detuned candidates cross lower.
    """
    phi_b = math.radians(phase_deg) % (2 * math.pi) - math.pi
    floor = max(-60.0, phase_margin_deg - MAX_PID_LEAD_DEG)
    phi_b = min(0.0, max(math.radians(floor), phi_b))
    lead = math.radians(phase_margin_deg) - phi_b
    tan = math.tan(lead)
    x = (tan + math.sqrt(tan * tan + 4.0 / alpha)) / 2.0  # x - 1/(alpha x) = tan
    td = x / w
    ti = alpha * td
    p = math.cos(lead) / gain
    return p, p / ti, p * td


@register_tuner
class RelayTuner(Tuner):
    """Relay-feedback identification with the Astrom-Hagglund phase-margin rule.

    The chip acts as a relay on the axis velocity (a saturated derivative term sampled every
    N servo cycles, a weak position term to stay centred; the motor limit is the relay
    amplitude, doubled until the axis oscillates). The oscillation's period and first
    harmonics give one point of the plant's frequency response and the holding command
    (the relay's mean output). The rule designs a PID with 45 degrees of phase margin at
    that frequency (and at half of it); the bias is the holding command, the acceleration
    feed-forward the inverse of the identified acceleration gain. Three relay frequencies
    (N = 8, 16, 32) give six candidates; the best is kept.
    """

    name = "relay"
    min_budget = 6

    def run(self, session: Session) -> None:
        session.evaluate_warm_start()
        ctx = _Context(session)
        step = int(min(max(50.0, 0.01 * ctx.move_counts), 5000.0))
        n_ticks = _ticks(0.4, ctx.dt)
        profile = _Profile.setpoints([(step, n_ticks)])
        designs: list[tuple[ServoDesign, str]] = []
        for n_cycles in (8, 16, 32):
            m = 0.02 * FULL_SCALE
            result = None
            while m <= FULL_SCALE and session.remaining > 2:
                relay = ServoDesign(
                    p=m / step,
                    d=m * n_cycles * ctx.dt,
                    motor_limit=m,
                    derivative_sample_s=n_cycles * ctx.dt,
                )
                result = ctx.run(
                    relay,
                    profile,
                    f"relay: N={n_cycles}, amplitude {m:.0f}",
                    lambda tr: _relay_measure(tr, ctx.dt),
                )
                if not result["diverged"] and result["oscillates"]:
                    break
                m *= 2
                result = None
            if result is None:
                continue
            w = 2 * math.pi / result["period_s"]
            accel_gain = w * w * result["gain"]  # counts/s^2 per command count
            p, i, d = astrom_hagglund(w, result["gain"], result["phase_deg"])
            base = ServoDesign(
                p=p, i=i, d=d,
                integral_limit=0.1 * FULL_SCALE,
                bias=result["mean_command"],
                aff=1.0 / accel_gain,
            )  # fmt: skip
            designs.append((base, f"relay N={n_cycles}: rule at {w / 2 / math.pi:.0f} Hz"))
            designs.append(
                (
                    base.replace(p=p / 4, i=i / 8, d=d / 2),
                    f"relay N={n_cycles}: rule at {w / 4 / math.pi:.0f} Hz (detuned x2)",
                )
            )
        if not designs:
            raise TuneError(
                "relay: the axis never oscillated under the relay (up to full scale); "
                "no frequency-response point to tune from"
            )
        ctx.candidates(designs)


# ------------------------------------------------------------------------------------------
# Model-based rule from an identification experiment
# ------------------------------------------------------------------------------------------


def identify_rigid_axis(
    command: np.ndarray, position: np.ndarray, dt: float, block: int = 8
) -> dict[str, float]:
    """Least-squares fit of ``a = g*u - c*sign(v) - b*v - h`` to one run's traces.

    Velocity changes over blocks of ``block`` ticks are regressed on the command, friction
    and offset integrated over the block (robust to encoder quantization).

    Returns:
        ``accel_gain`` g (counts/s^2 per command count), ``coulomb_cmd`` c/g and
        ``gravity_cmd`` h/g (command counts), ``viscous_cmd`` b/g (command counts per
        count/s), and ``fit_rms`` the RMS residual relative to the RMS velocity change.
    """
    x = position.astype(float)
    u = command.astype(float)
    half = block // 2
    k = np.arange(block, len(x) - 2 * block, block)
    if k.size < 8:
        raise TuneError("the identification run is too short to fit a model")

    def vel(i: np.ndarray) -> np.ndarray:
        return (x[i + half] - x[i - half]) / (block * dt)

    v0, v1 = vel(k), vel(k + block)
    dv = v1 - v0
    vm = 0.5 * (v0 + v1)
    span = block * dt
    su = np.array([u[i : i + block].sum() * dt for i in k])
    rows = np.column_stack([su, -np.sign(vm) * span, -vm * span, -np.full(k.size, span)])
    keep = np.abs(vm) > 0
    coef, *_ = np.linalg.lstsq(rows[keep], dv[keep], rcond=None)
    g, c, b, h = (float(v) for v in coef)
    resid = dv[keep] - rows[keep] @ coef
    scale = float(np.sqrt(np.mean(dv[keep] ** 2))) or 1.0
    return {
        "accel_gain": g,
        "coulomb_cmd": c / g if g else 0.0,
        "viscous_cmd": b / g if g else 0.0,
        "gravity_cmd": h / g if g else 0.0,
        "fit_rms": float(np.sqrt(np.mean(resid**2))) / scale,
    }


def _hold_measure(traces: Any, n_hold: int, dt: float) -> dict[str, Any]:
    """The holding command of a closed-loop hold (its last half), and how still it held."""
    u = traces.command[:n_hold].astype(float)
    x = traces.actual[:n_hold].astype(float)
    tail = slice(n_hold // 2, n_hold)
    drift = float(abs(x[tail][-1] - x[tail][0])) / (0.5 * n_hold * dt)
    return {
        "hold_cmd": float(u[tail].mean()),
        "hold_spread": float(u[tail].std()),
        "hold_error": float(x[tail].mean()),
        "drift_counts_per_s": drift,
    }


@register_tuner
class ModelBasedTuner(Tuner):
    """A model-based rule from a short identification experiment that first holds the load.

    1. *Hold, then move* (motor limit 100 %): a PD holds the axis at its start position
       for 0.15 s, then moves up and back under the same loop; the least-squares fit of the
       whole run (below) gives the static load, the command that holds the axis still
       (gravity; 0 on a horizontal axis), or the mean command of the hold's second half if
       the fit fails.
    2. *Move around the hold* (motor limit the holding command + 20 % of full scale, bias the
       holding command): a saturated PD moves up and back, the command swinging around the
       one that holds the load, so that a load needing half the motor (an arm at 3 kg) is
       held and still moved.

    Both moves identify a rigid axis by least squares: acceleration per command count
    (inertia), Coulomb and viscous friction, and the gravity holding command. The PID
    places the closed-loop poles at ``(s + w)^3`` (``p = 3w^2/g``, ``d = 3w/g``,
    ``i = w^3/g``), the derivative sampled at most every ``1/(4w)`` to quiet encoder
    quantization; bias = gravity, Kvff = viscous friction, Kaff = inertia. Seven bandwidths
    ``w = 1/(6.5 Ts) * 2^-k``, k = 0..6, are candidates (the lowest keep the loop below a
    resonance, for the margins); the best is kept.
    """

    name = "model-based"
    min_budget = 4

    hold_s = 0.15
    """Duration of the hold before the first move, in seconds."""

    def run(self, session: Session) -> None:
        session.evaluate_warm_start()
        ctx = _Context(session)
        amplitude = int(max(200.0, 0.25 * ctx.move_counts))
        half = _ticks(0.25, ctx.dt)
        n_hold = _ticks(self.hold_s, ctx.dt)
        move = [(amplitude, half), (0, half)]
        fits = []

        def identify(tr: Any, start: int) -> dict[str, Any]:
            return identify_rigid_axis(tr.command[start:], tr.actual[start:], ctx.dt)

        # 1. Hold at the start position (full motor), then move: the static load.
        p = 0.1 * FULL_SCALE / (amplitude / 8)
        design = ServoDesign(p=p, d=p * 0.01, motor_limit=FULL_SCALE - 1,
                             derivative_sample_s=8 * ctx.dt)  # fmt: skip

        def measure_hold(tr: Any) -> dict[str, Any]:
            out = _hold_measure(tr, n_hold, ctx.dt)
            try:
                out.update(identify(tr, 0))  # the fall into the hold identifies too
            except TuneError:
                out["accel_gain"] = 0.0
            return out

        profile = _Profile.setpoints([(0, n_hold), *move])
        r = ctx.run(design, profile, "hold the load, then identification move, limit 100%",
                    measure_hold)  # fmt: skip
        hold = 0.0
        if not r["diverged"]:
            # The fitted holding command; the mean command of the hold if the fit failed
            # (a hold still swinging at its end reads high or low, the fit does not).
            hold = r["gravity_cmd"] if r["accel_gain"] > 0 else r["hold_cmd"]
            hold = min(max(hold, -0.9 * FULL_SCALE), 0.9 * FULL_SCALE)
            if r["accel_gain"] > 0:
                fits.append(r)
        # 2. Move around the holding command, a swing of 20 % of full scale.
        level = 0.2
        p = level * FULL_SCALE / (amplitude / 8)
        limit = min(FULL_SCALE - 1, abs(hold) + level * FULL_SCALE)
        design = ServoDesign(p=p, d=p * 0.01, bias=hold, motor_limit=limit,
                             derivative_sample_s=8 * ctx.dt)  # fmt: skip
        r = ctx.run(
            design,
            _Profile.setpoints(move),
            f"identification move around the hold ({hold / FULL_SCALE:.0%}), swing {level:.0%}",
            lambda tr: identify(tr, 0),
        )
        if not r["diverged"] and r["accel_gain"] > 0:
            fits.append(r)
        if not fits:
            raise TuneError(
                "model-based: every identification move diverged or gave no positive "
                "acceleration gain; the plant cannot be identified as a rigid axis"
            )
        keys = ("accel_gain", "coulomb_cmd", "viscous_cmd", "gravity_cmd", "fit_rms")
        model = {k: float(np.mean([f[k] for f in fits])) for k in keys}
        identified = getattr(session, "on_identified", None)
        if identified is not None:  # the safe tuner predicts margins on this model
            identified(model)
        ctx.candidates(pole_placement_designs(model["accel_gain"], ctx.dt,
                                              gravity_cmd=model["gravity_cmd"],
                                              viscous_cmd=model["viscous_cmd"]))  # fmt: skip


N_BANDWIDTHS = 7
"""Candidate bandwidths of the model-based design, ``w = 1/(6.5 Ts) * 2^-k``, k = 0..6."""


def pole_placement_designs(
    accel_gain: float, dt: float, *, gravity_cmd: float = 0.0, viscous_cmd: float = 0.0
) -> list[tuple[ServoDesign, str]]:
    """The model-based rule's :data:`N_BANDWIDTHS` candidate designs, fastest first.

    The PID places the closed-loop poles of a rigid axis at ``(s + w)^3`` (``p = 3w^2/g``,
    ``d = 3w/g``, ``i = w^3/g``), its derivative sampled at most every ``1/(4w)``; bias =
    the gravity holding command, Kvff = the viscous friction, Kaff = the inertia.

    Args:
        accel_gain: ``g``, the axis's acceleration per command count (counts/s^2), > 0.
        dt: The servo period (s).
        gravity_cmd: The command that holds the load (command counts).
        viscous_cmd: Command per count/s of velocity (viscous friction).

    Returns:
        ``(design, note)`` pairs.
    """
    g = accel_gain
    w0 = 1.0 / (6.5 * dt)
    designs = []
    for k in range(N_BANDWIDTHS):
        w = w0 / 2**k
        d = 3 * w / g
        quantum = 0.01 * FULL_SCALE  # largest command step one count of D may cause
        n = max(1, min(round(1 / (4 * w * dt)), math.ceil(d / (dt * quantum))))
        design = ServoDesign(
            p=3 * w * w / g,
            i=w**3 / g,
            d=d,
            integral_limit=0.1 * FULL_SCALE + abs(gravity_cmd),
            bias=gravity_cmd,
            vff=max(0.0, viscous_cmd),
            aff=1.0 / g,
            derivative_sample_s=n * dt,
        )
        designs.append((design, f"model-based: poles at -{w:.0f} rad/s"))
    return designs
