"""Plain-Python reference of the Turbo PMAC servo filter: docs/chips/pmac.md, section 3.

Slow and obvious on purpose. Python integers never overflow, so every width limit written in
the spec appears here as an explicit ``wrap32``/``sat``/``clamp``; the numba kernel in
``_kernel.py`` must give bit-identical outputs (tests/chips/test_pmac_filter.py).
"""

from __future__ import annotations

from servogym.chips.pmac._params import PMACAssumptions, PMACParams

S16 = (-(2**15), 2**15 - 1)
S24 = (-(2**23), 2**23 - 1)
S32 = (-(2**31), 2**31 - 1)
S48 = (-(2**47), 2**47 - 1)


def wrap32(x: int) -> int:
    """Two's-complement wrap to signed 32 bits (what a 32-bit register does on overflow)."""
    return (x + 2**31) % 2**32 - 2**31


def clamp(x: int, lo: int, hi: int) -> int:
    """Saturate ``x`` to ``lo..hi``."""
    return lo if x < lo else hi if x > hi else x


def sat(x: int, bits: int) -> int:
    """Saturate to a signed ``bits``-bit value."""
    return clamp(x, -(2 ** (bits - 1)), 2 ** (bits - 1) - 1)


def shift_right(x: int, n: int, rounding: str) -> int:
    """Divide by ``2**n``: ``"floor"`` shifts arithmetically, ``"trunc"`` rounds to 0 (PMAC-A1)."""
    if rounding == "floor" or x >= 0:
        return x >> n
    return -((-x) >> n)


def sign(x: int) -> int:
    """-1, 0 or 1."""
    return (x > 0) - (x < 0)


class PMACReferenceFilter:
    """One motor's Turbo PMAC PID + feed-forward + notch filter, once per servo update.

    Args:
        params: The register values (I-variables of one motor).
        assumptions: The choice for every unsettled point of the spec.

    Attributes:
        integrator: IS, the integrator sum (units 2^-24 of 1/16 count of integrator output).
        commanded_prev, fraction_prev, actual_prev: CP and AP of the previous cycle.
        velocity_prev: CV of the previous cycle in internal units (for CA).
        saturated: Direction the output limit clamped last cycle (-1, 0, 1).
        cycle: Servo updates since reset (n).
        motion_error: Latched fatal following error (Ixx11, or Ixx63 < 0).
        notch_state: ``[x1, x2, w1, w2]`` (direct form I) or ``[v1, v2, 0, 0]`` (form II).
    """

    def __init__(self, params: PMACParams, assumptions: PMACAssumptions | None = None) -> None:
        self.params = params
        self.assumptions = assumptions or PMACAssumptions()
        self.reset()

    def reset(self) -> None:
        """Zero every state, as when the loop is closed."""
        self.integrator = 0
        self.commanded_prev = 0
        self.fraction_prev = 0
        self.actual_prev = 0
        self.velocity_prev = 0
        self.saturated = 0
        self.cycle = 0
        self.motion_error = False
        self.notch_state = [0, 0, 0, 0]

    def update(self, params: PMACParams) -> None:
        """Load a new register set (I-variables written on the fly); the state is kept."""
        self.params = params

    def _shr(self, x: int, n: int) -> int:
        return shift_right(x, n, self.assumptions.rounding)

    def _notch(self, x: int, bits: int) -> int:
        """Section 3.8: F(z) = (1 + n1 z^-1 + n2 z^-2) / (1 + d1 z^-1 + d2 z^-2)."""
        p = self.params
        n1, n2, d1, d2 = p.notch_n1, p.notch_n2, p.notch_d1, p.notch_d2
        s = self.notch_state
        if self.assumptions.notch_form == "df1":
            x1, x2, w1, w2 = s
            acc = x * 2**22 + n1 * x1 + n2 * x2 - d1 * w1 - d2 * w2
            w = sat(self._shr(acc, 22), bits)
            self.notch_state = [x, x1, w, w1]
            return w
        v1, v2 = s[0], s[1]
        v = sat(self._shr(x * 2**22 - d1 * v1 - d2 * v2, 22), bits)
        w = sat(self._shr(v * 2**22 + n1 * v1 + n2 * v2, 22), bits)
        self.notch_state = [v, v1, 0, 0]
        return w

    def _integrate(self, e_int: int, cv: int, saturated: int) -> None:
        """Section 3.6: add Ixx33 * E to the integrator, within Ixx63, unless held."""
        p, a = self.params, self.assumptions
        if p.integration_mode == 1 and cv != 0:
            return  # Ixx34 = 1: only while the commanded velocity is zero; output held.
        limit = abs(p.integration_limit) * 2**24
        new = clamp(self.integrator + p.integral_gain * e_int, -limit, limit)
        growing = abs(new) > abs(self.integrator)
        if saturated != 0 and (a.anti_windup == "freeze" or growing):
            return
        self.integrator = new

    def step(self, commanded: int, actual: int, fraction: int = 0, _unused: int = 0) -> int:
        """Run one servo update and return the output command (signed 16-bit DAC value).

        Args:
            commanded: Commanded position, whole counts, signed 32-bit (wrapped).
            actual: Actual (encoder) position, counts, signed 32-bit (wrapped).
            fraction: The commanded position's fraction in 1/32 count (0..31; only the low
                5 bits are read): the commanded position is ``commanded + fraction/32``.
            _unused: The profile's fourth input; this filter does not read it.
        """
        p, a = self.params, self.assumptions
        wbits = 24 if a.velocity_words == "s24" else 32
        f = fraction & 31

        # 3.1 Following error in 1/32 count.
        fe = 32 * wrap32(commanded - actual) + f
        if self.cycle == 0:
            if a.first_cycle == "actual":
                self.commanded_prev, self.fraction_prev = actual, 0
            else:
                self.commanded_prev, self.fraction_prev = commanded, f
            self.actual_prev = actual
            self.velocity_prev = 0

        # 3.2 Safety: fatal following error (Ixx11) and integrated error (Ixx63 < 0).
        if p.fatal_following_error_limit > 0:
            lim = 2 * p.fatal_following_error_limit
            if (abs(fe) > lim) if a.trip_compare == "greater" else (abs(fe) >= lim):
                self.motion_error = True
        if p.integration_limit < 0 and abs(self.integrator) >= -p.integration_limit * 2**24:
            self.motion_error = True

        # 3.3 Big-step limit (Ixx67, 1/16 count).
        fe_b = clamp(fe, -2 * p.big_step_limit, 2 * p.big_step_limit)

        # 3.4 Deadband (Ixx64 gain factor, Ixx65 size in 1/16 count).
        band = 2 * p.deadband_size
        g = p.deadband_gain
        if abs(fe_b) < band:
            fe_d = self._shr(fe_b * (16 + g), 4)
        elif a.deadband_outside == "offset":
            offset = self._shr(g * band, 4)
            fe_d = fe_b + offset if fe_b >= 0 else fe_b - offset
        else:
            fe_d = fe_b

        # 3.5 Velocities: commanded velocity and acceleration, actual velocity.
        cv32 = 32 * wrap32(commanded - self.commanded_prev) + (f - self.fraction_prev)
        cv = sat(p.position_loop_scale * cv32, wbits)
        ca = sat(cv - self.velocity_prev, wbits)
        av = sat(p.velocity_loop_scale * 32 * wrap32(actual - self.actual_prev), wbits)

        # 3.6 Integrator, before the output when PMAC-A2 is "current".
        e_int = fe_d if a.integrator_input == "deadband" else fe_b
        if a.integral_timing == "current":
            self._integrate(e_int, cv32, self.saturated)

        # 3.7 Servo sum in internal units (1/(32*Ixx08) count).
        ff = self._shr(p.velocity_ff * cv + p.acceleration_ff * ca, 7)
        io = self._shr(self.integrator, 23)
        pos = sat(p.position_loop_scale * fe_d + ff + p.position_loop_scale * io, 48)
        y = sat(pos - self._shr(p.derivative_gain * av, 7), 48)

        # 3.8 Ixx30 and the notch: the 24-bit output word O.
        if a.notch_position == "after_kp":
            o = sat(self._shr(p.proportional_gain * y, 16), 24)
            o = self._notch(o, 24)
        else:
            w = self._notch(sat(y, 32), 32)
            o = sat(self._shr(p.proportional_gain * w, 16), 24)

        # 3.9 DAC value (bits 8..23), friction feed-forward, output limit, bias.
        x = o >> 8
        friction = p.friction_ff * sign(cv32)
        if a.friction_order == "before_limit":
            x += friction
        if a.bias_order == "bias_then_limit":
            x += p.output_bias
        limited = clamp(x, -p.output_limit, p.output_limit)
        saturated = sign(x) if limited != x else 0
        if a.friction_order == "after_limit":
            limited += friction
        if a.bias_order == "limit_then_bias":
            limited += p.output_bias
        command = sat(limited, 16)

        # 3.6 Integrator, after the output (PMAC-A2 default "previous").
        if a.integral_timing == "previous":
            self._integrate(e_int, cv32, saturated)
        self.saturated = saturated

        # 3.10 A killed motor.
        if self.motion_error and a.trip_action != "flag_only":
            command = 0 if a.trip_action == "kill" else p.output_bias

        # 3.11 State for the next cycle.
        self.commanded_prev, self.fraction_prev = commanded, f
        self.actual_prev = actual
        self.velocity_prev = cv
        self.cycle += 1
        return command

    def run(self, commanded, actual, fraction, aux=None) -> list[int]:
        """Run :meth:`step` over equal-length sequences; return the output commands."""
        if aux is None:
            aux = [0] * len(commanded)
        return [
            self.step(int(c), int(x), int(f), int(u))
            for c, x, f, u in zip(commanded, actual, fraction, aux, strict=True)
        ]
