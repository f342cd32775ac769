"""Plain-Python reference of the PMD servo filter: docs/chips/pmd.md, section 3, line by line.

Slow and obvious on purpose. Python integers never overflow, so every width limit written in
the spec appears here as an explicit ``wrap32``/``sat16``/``clamp``; the numba kernel in
``_kernel.py`` must give bit-identical motor commands (tests/chips/test_pmd_filter.py).
"""

from __future__ import annotations

from servogym.chips.pmd._params import PMDAssumptions, PMDParams

S16 = (-(2**15), 2**15 - 1)
S32 = (-(2**31), 2**31 - 1)
S48 = (-(2**47), 2**47 - 1)


def wrap32(x: int) -> int:
    """Two's-complement wrap to signed 32 bits (what a 32-bit register does on overflow)."""
    return (x + 2**31) % 2**32 - 2**31


def clamp(x: int, lo: int, hi: int) -> int:
    """Saturate ``x`` to ``lo..hi``."""
    return lo if x < lo else hi if x > hi else x


def sat16(x: int) -> int:
    """Saturate to signed 16 bits."""
    return clamp(x, *S16)


def sat32(x: int) -> int:
    """Saturate to signed 32 bits."""
    return clamp(x, *S32)


def shift_right(x: int, n: int, rounding: str) -> int:
    """Divide by ``2**n``: ``"floor"`` shifts arithmetically, ``"trunc"`` rounds to 0 (PMD-A1)."""
    if rounding == "floor" or x >= 0:
        return x >> n
    return -((-x) >> n)


class PMDReferenceFilter:
    """One axis of the PMD position loop, evaluated once per servo cycle.

    Args:
        params: The register values (applied as after an Update).
        assumptions: The choice for every unsettled point of the spec.

    Attributes:
        integral: I, the limited error sum (counts*cycles).
        error_at_sample: E at the last derivative sample instant.
        derivative: D, the held derivative difference.
        previous_error: E of the previous cycle.
        cycle: Cycles since reset (n).
        motion_error: Latched motion-error flag.
        biquad_state: Per stage ``[x1, x2, y1, y2]``.
    """

    def __init__(self, params: PMDParams, assumptions: PMDAssumptions | None = None) -> None:
        self.params = params
        self.assumptions = assumptions or PMDAssumptions()
        self.reset()

    def reset(self) -> None:
        """Zero every state, as at power-up or after a reset."""
        self.integral = 0
        self.error_at_sample = 0
        self.derivative = 0
        self.previous_error = 0
        self.cycle = 0
        self.motion_error = False
        self.biquad_state = [[0, 0, 0, 0], [0, 0, 0, 0]]

    def update(self, params: PMDParams) -> None:
        """Load a new register set (the chip's Update); the filter state is kept."""
        self.params = params

    def _shr(self, x: int, n: int) -> int:
        return shift_right(x, n, self.assumptions.rounding)

    def _biquad(self, stage: int, x: int) -> int:
        """One biquad stage (spec 3.7): signed 32-bit in, signed 32-bit out."""
        p, a = self.params, self.assumptions
        frac = 14 if a.biquad_format == "q14" else 15
        b0, b1, b2, a1, a2, k = (
            getattr(p, f"biquad{stage}_{n}") for n in ("b0", "b1", "b2", "a1", "a2", "k")
        )
        x1, x2, y1, y2 = self.biquad_state[stage - 1]
        acc = b0 * x + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2
        w = sat32(self._shr(acc, frac))
        self.biquad_state[stage - 1] = [x, x1, w, y1]
        return sat32(self._shr(k * w, frac))

    def step(self, commanded: int, actual: int, velocity: int, acceleration: int) -> int:
        """Run one servo cycle and return the motor command (signed 16-bit).

        Args:
            commanded: Commanded position from the profile generator, signed 32-bit counts.
            actual: Actual (encoder) position, signed 32-bit counts.
            velocity: Commanded velocity, 16.16 counts/cycle (signed 32-bit).
            acceleration: Commanded acceleration, 16.16 counts/cycle^2 (signed 32-bit).
        """
        p, a = self.params, self.assumptions
        n = self.cycle

        # 3.1 Position error: 32-bit wrapped difference; motion error on its magnitude.
        e32 = wrap32(commanded - actual)
        if a.error_limit_compare == "greater":
            exceeded = abs(e32) > p.position_error_limit
        else:
            exceeded = abs(e32) >= p.position_error_limit
        if exceeded:
            self.motion_error = True
        e = sat16(e32) if a.error_saturation == "sat16" else e32

        # 3.2 Integral: the error sum, limited to +-integration_limit.
        self.integral = clamp(self.integral + e, -p.integration_limit, p.integration_limit)

        # 3.3 Derivative: sampled every derivative_time cycles, held in between.
        if n % p.derivative_time == 0:
            if a.derivative_mode == "sample_difference":
                d = e - self.error_at_sample
            else:
                d = e - self.previous_error
            self.error_at_sample = e
            self.derivative = sat16(d) if a.derivative_saturation == "sat16" else d
        self.previous_error = e

        # 3.4 Feed-forward terms.
        if a.feedforward_input == "integer":
            ff = p.kvff * self._shr(velocity, 16) + p.kaff * self._shr(acceleration, 16)
        else:
            ff = self._shr(p.kvff * velocity, 16) + self._shr(p.kaff * acceleration, 16)

        # 3.5 The PID sum.
        integral_term = self._shr(p.ki * self.integral, int(a.integral_shift))
        u = p.kp * e + p.kd * self.derivative + integral_term
        if a.kout_scales_feedforward == "yes":
            u += ff

        # 3.6 Accumulator saturation.
        u = sat32(u) if a.accumulator == "sat32" else clamp(u, *S48)

        # 3.7 Biquad stages (MC58000), each bypassed unless enabled.
        for stage in (1, 2):
            if getattr(p, f"biquad{stage}_enable"):
                u = self._biquad(stage, sat32(u))

        # 3.8 Output scaling by kout/65536.
        y = self._shr(u * p.kout, 16)
        if a.kout_scales_feedforward == "no":
            y += ff

        # 3.9 Bias and motor limit.
        if a.bias_order == "bias_then_limit":
            command = clamp(y + p.bias, -p.motor_limit, p.motor_limit)
        else:
            command = sat16(clamp(y, -p.motor_limit, p.motor_limit) + p.bias)

        # 3.10 Motion error stops the motor (auto-stop).
        if self.motion_error and a.motion_error == "stop":
            command = 0

        self.cycle = n + 1
        return command

    def run(self, commanded, actual, velocity, acceleration) -> list[int]:
        """Run :meth:`step` over equal-length sequences; return the motor commands."""
        return [
            self.step(int(c), int(x), int(v), int(a))
            for c, x, v, a in zip(commanded, actual, velocity, acceleration, strict=True)
        ]
