"""Plain-Python reference of the 6000-series PIV&F filter: docs/chips/parker6k.md, section 4.

Slow and obvious on purpose. Python integers never overflow, so every width the spec names
appears here as an explicit ``wrap32``/``sat``/``clamp``; the numba kernel in ``_kernel.py``
must give bit-identical motor commands (tests/chips/test_parker6k_filter.py).
"""

from __future__ import annotations

from servogym.chips.parker6k._params import Parker6kAssumptions, Parker6kParams

W = 2**47
"""Saturation of every term and of their sum, in signal units q (spec 4.0)."""
MICRO = 1_000_000
S32 = (-(2**31), 2**31 - 1)


def wrap32(x: int) -> int:
    """Two's-complement wrap to signed 32 bits."""
    return (x + 2**31) % 2**32 - 2**31


def clamp(x: int, lo: int, hi: int) -> int:
    """Saturate ``x`` to ``lo..hi``."""
    return lo if x < lo else hi if x > hi else x


def sat(x: int, w: int) -> int:
    """Saturate ``x`` to ``-w..w``."""
    return clamp(x, -w, w)


def divide(x: int, d: int, rounding: str) -> int:
    """``x / d`` for ``d > 0``: ``"floor"`` rounds toward -infinity, ``"trunc"`` toward 0."""
    if rounding == "floor" or x >= 0:
        return x // d
    return -((-x) // d)


def scale_of(assumptions: Parker6kAssumptions) -> tuple[int, int, int]:
    """``(FS, MV, N)``: signal units q in 10 V, q in 1 mV, and the DAC's half range."""
    fs = 10**9 if assumptions.gain_unit == "uV" else 10**6
    return fs, fs // 10_000, 2 ** (int(assumptions.dac_bits) - 1)


class Parker6kReferenceFilter:
    """One servo axis of the 6000-series PIV&F filter, evaluated once per servo sample.

    Args:
        params: The settings in force (stored gain sets and SGENB schedule included).
        assumptions: The choice for every unsettled point of the spec.

    Attributes:
        integral: The integrator state: the integral term in q/10^6 (PK-A4
            ``accumulator``) or the 32-bit error sum (``output``, ``conditional``).
        previous_actual: Encoder position of the previous sample.
        previous_error: Position error of the previous sample.
        active_set: Gain set in force at the last sample (0 = the active gains at reset).
        cycle: Servo samples since reset (n).
        tripped: Latched SMPER shutdown.
    """

    def __init__(
        self, params: Parker6kParams, assumptions: Parker6kAssumptions | None = None
    ) -> None:
        self.params = params
        self.assumptions = assumptions or Parker6kAssumptions()
        self.reset()

    def reset(self) -> None:
        """Zero every state, as at power-up."""
        self.integral = 0
        self.previous_actual = 0
        self.previous_error = 0
        self.active_set = 0
        self.cycle = 0
        self.tripped = False

    @property
    def motion_error(self) -> bool:
        """The latched SMPER shutdown, under the name the runner's Python twin reads."""
        return self.tripped

    def update(self, params: Parker6kParams) -> None:
        """Load new settings; the filter state is kept (commands sent between samples)."""
        self.params = params

    def _div(self, x: int, d: int) -> int:
        return divide(x, d, self.assumptions.rounding)

    def step(self, commanded: int, actual: int, velocity: int, acceleration: int) -> int:
        """Run one servo sample and return the motor command (signed 16-bit).

        Args:
            commanded: Commanded position, signed 32-bit counts.
            actual: Encoder position, signed 32-bit counts.
            velocity: Commanded velocity, counts/s (integer).
            acceleration: Commanded acceleration, counts/s^2 (integer).
        """
        p, a = self.params, self.assumptions
        n = self.cycle
        fs, mv, half = scale_of(a)
        period = p.sample_time_us

        # 4.1 Position error and the SMPER shutdown.
        e = wrap32(commanded - actual)
        if p.smper > 0 or a.smper_zero == "limit":
            over = abs(e) > p.smper if a.smper_compare == "greater" else abs(e) >= p.smper
            if over:
                self.tripped = True

        # 4.2 The gain set in force: the last SGENB switch at or before this sample.
        self.active_set = 0
        for tick, number in p.sgenb:
            if tick <= n:
                self.active_set = number
        g = p.gains if self.active_set == 0 else p.sgset[self.active_set - 1]

        # 4.3 Velocity input, counts/sample (0 on the first sample after reset).
        if a.velocity_feedback == "encoder":
            x = 0 if n == 0 else wrap32(actual - self.previous_actual)
        else:
            x = 0 if n == 0 else e - self.previous_error
        self.previous_actual = actual
        self.previous_error = e

        # 4.4 Proportional term.
        t_p = sat(g.sgp * e, W)

        # 4.5 Velocity term: SGV times counts/s (x * 10^6 / period), sign by PK-A3.
        sign = -1 if a.velocity_feedback == "encoder" else 1
        t_v = sat(self._div(sign * g.sgv * x * MICRO, period), W)

        # 4.6 Integral term, limited by SGILIM (PK-A4); lim in q/10^6.
        lim = p.sgilim * mv * MICRO

        def integral_term() -> int:
            if a.integral_limit == "accumulator":
                return self._div(self.integral, MICRO)
            return self._div(sat(g.sgi * self.integral * period, lim), MICRO)

        term_before = integral_term()
        if a.integral_limit == "accumulator":
            self.integral = sat(self.integral + g.sgi * e * period, lim)
        else:
            candidate = clamp(self.integral + e, *S32)
            if a.integral_limit == "output" or abs(g.sgi * candidate * period) <= lim:
                self.integral = candidate
        # PK-A10: the output takes the term after this sample's update ("current") or
        # the one the previous sample left ("previous").
        t_i = integral_term() if a.integral_timing == "current" else term_before

        # 4.7 Feed-forward terms.
        t_vf = sat(g.sgvf * velocity, W)
        t_af = sat(self._div(g.sgaf * acceleration, 100), W)

        # 4.8 Control signal, offset and DAC.
        u = sat(t_p + t_v + t_i + t_vf + t_af, W)
        offset = p.soffs * mv
        if a.offset_order == "offset_then_saturate":
            y = u + offset
        else:
            y = sat(u, fs) + offset
        code = clamp(self._div(y * half, fs), -half, half - 1)

        # 4.9 Shutdown.
        if self.tripped:
            code = 0
        self.cycle = n + 1
        return code * (2**15 // half)

    def run(self, commanded, actual, velocity, acceleration) -> list[int]:
        """Run :meth:`step` over equal-length sequences; return the motor commands."""
        return [
            self.step(int(c), int(x), int(v), int(a))
            for c, x, v, a in zip(commanded, actual, velocity, acceleration, strict=True)
        ]
