"""A set's loop margins predicted on the rigid axis the model-based design identified.

The safe tuner (:mod:`servogym.autotune._safe`) uses it to leave out, before they run, the
sets whose margins the model says are short: what an engineer does with the model of an
identification run. The model is the one :class:`~servogym.autotune.ModelBasedTuner` fits,
``a = g u - b v - ...``: a rigid axis with acceleration ``g`` per command count and viscous
friction ``b`` (``viscous_cmd = b / g``), behind the amplifier's current-loop lag (the
drive's datasheet value: the plant's ``current_bandwidth_hz``), sampled at the set's period
after the chip's loop latency. It knows nothing of a resonance or of gravity's stiffness, so
:class:`MarginPredictor` also learns how optimistic it is from the sets already evaluated
(:meth:`MarginPredictor.calibrate`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from servogym.sim._margins import Margins, discretize, margins_only
from servogym.sim._operating import severity


class MarginPredictor:
    """Gain and phase margins of register sets on an identified rigid axis.

    Args:
        problem: The tuning problem (its chip, scenario and space).
        io: The plant's I/O (``current_bandwidth_hz`` of its amplifier).
        accel_gain: ``g``, counts/s^2 per command count (> 0).
        viscous_cmd: Command counts per count/s of velocity (the design's fit; >= 0 used).
    """

    def __init__(self, problem: Any, io: Any, accel_gain: float, viscous_cmd: float) -> None:
        if not (math.isfinite(accel_gain) and accel_gain > 0):
            raise ValueError(f"accel_gain must be finite and > 0; got accel_gain={accel_gain}")
        self.problem = problem
        sc = problem.scenario
        self.chip = sc.chip
        self.assumptions = sc.assumptions or self.chip.default_assumptions()
        g, b = float(accel_gain), max(0.0, float(viscous_cmd)) * float(accel_gain)
        bw = float(getattr(io, "current_bandwidth_hz", 0.0) or 0.0)
        if bw > 0:  # state: position, velocity (counts, counts/s), the lagged command
            tau = 1.0 / (2 * math.pi * bw)
            a = np.array([[0.0, 1.0, 0.0], [0.0, -b, g], [0.0, 0.0, -1.0 / tau]])
            bvec = np.array([0.0, 0.0, 1.0 / tau])
        else:
            a = np.array([[0.0, 1.0], [0.0, -b]])
            bvec = np.array([0.0, g])
        c = np.zeros(len(bvec))
        c[0] = 1.0
        self._continuous = (a, bvec, c, np.zeros(len(bvec)))
        self._linear: dict[tuple[float, float], Any] = {}
        self.bias = np.zeros(2)
        """How much the model overstates the margins (dB, degrees), from :meth:`calibrate`."""
        c = problem.constraints
        self.limits = (c.min_gain_margin_db, c.min_phase_margin_deg)
        """The problem's minimum gain margin (dB) and phase margin (degrees); ``None``: none."""

    def margins(self, values: Mapping[str, Any]) -> Margins:
        """The model's :class:`~servogym.sim._margins.Margins` of a register set."""
        params = self.problem.space.make_params(values)
        dt = self.chip.sample_time_s(params)
        latency = self.chip.loop_latency_s(params, self.assumptions)
        key = (dt, latency)
        if key not in self._linear:
            self._linear[key] = discretize(self._continuous, dt, latency)
        return margins_only(self.chip, params, self.assumptions, self._linear[key])

    def raw(self, values: Mapping[str, Any]) -> tuple[float, float]:
        """The model's gain margin (dB) and phase margin (degrees) of a register set; an
        unstable loop's are ``-inf``."""
        return self.pair(self.margins(values))

    @staticmethod
    def pair(m: Margins) -> tuple[float, float]:
        """``(gain margin dB, phase margin degrees)`` of ``m``; ``-inf`` when unstable."""
        if not m.stable:
            return -math.inf, -math.inf
        return float(m.gain_margin_db), float(m.phase_margin_deg)

    def severity(self, m: Margins) -> tuple[bool, float]:
        """:func:`~servogym.sim._operating.severity` of margins against the limits (smaller
        is worse); every unstable loop ranks the same, ``(False, -inf)``."""
        if not m.stable:
            return False, -math.inf
        return severity(m, *(x or 0.0 for x in self.limits))

    def clears(self, gm: float, pm: float, buffer: tuple[float, float]) -> bool:
        """Whether margins (dB, degrees) clear the limits by ``buffer``."""
        lo_gm, lo_pm = self.limits
        return (lo_gm is None or gm >= lo_gm + buffer[0]) and (
            lo_pm is None or pm >= lo_pm + buffer[1]
        )

    def calibrate(self, predicted: np.ndarray, measured: np.ndarray) -> None:
        """Learn the bias from sets evaluated: rows of (gain margin, phase margin), the
        model's and the evaluation's (the worst over the scenario's latencies and holding
        points). The bias is the largest overstatement, never below zero; rows where either
        is not finite say nothing."""
        p, m = np.asarray(predicted, float), np.asarray(measured, float)
        if p.size == 0:
            return
        ok = np.isfinite(p) & np.isfinite(m)
        over = np.where(ok, p - m, 0.0)
        self.bias = np.maximum(over.max(axis=0), 0.0)

    def predicted(self, values: Mapping[str, Any]) -> tuple[float, float]:
        """:meth:`raw` less the learnt bias."""
        gm, pm = self.raw(values)
        return gm - float(self.bias[0]), pm - float(self.bias[1])


def predictor_from_fit(session: Any, fit: Mapping[str, float]) -> MarginPredictor | None:
    """The predictor of a model-based fit (``accel_gain``, ``viscous_cmd``), or ``None``
    when the fit has no positive acceleration gain or the problem has no margin limits."""
    c = session.problem.constraints
    if not c.enabled or (c.min_gain_margin_db is None and c.min_phase_margin_deg is None):
        return None
    g = float(fit.get("accel_gain", 0.0))
    if not (math.isfinite(g) and g > 0):
        return None
    io = session.identification_evaluator.plant.io
    return MarginPredictor(session.problem, io, g, float(fit.get("viscous_cmd", 0.0)))
