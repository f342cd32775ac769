"""Delta Tau Turbo PMAC / Geo Brick LV: chip models, assumption switches and parameter sets.

Every number here is also in ``docs/chips/pmac.md``; ``tests/chips/test_pmac_docs.py`` checks
that the spec's tables match this module. Registers are the controller's I-variables for one
motor ``xx`` (``Ixx30`` is ``I130`` for motor 1, ``I1030`` for motor 10) plus the three global
clock I-variables ``I7000``..``I7002`` that set the servo period.
"""

from __future__ import annotations

import dataclasses
from fractions import Fraction
from typing import ClassVar

from servogym.chips._assumptions import AssumptionSet
from servogym.chips._registers import Register, RegisterSet, RegisterTable, Spelling
from servogym.chips._space import ParameterSpace, resolve_name

SPEC_VERSION = "pmac-spec-2"
"""Version of ``docs/chips/pmac.md`` the filter implements; written into exported files."""

S24_MIN, S24_MAX = -(2**23), 2**23 - 1
U23_MAX = 2**23 - 1
S16_MIN, S16_MAX = -(2**15), 2**15 - 1
U15_MAX = 2**15 - 1

MASTER_CLOCK_HZ = 117_964_800
"""The PMAC2-style Servo IC's master clock (117.9648 MHz); the clock dividers count it."""

COEFFICIENT_FRACTION_BITS = 22
"""Ixx36..Ixx39 are 24-bit words with one sign bit, one integer bit and 22 fractional bits."""


@dataclasses.dataclass(frozen=True)
class PMACChipModel:
    """One Delta Tau controller model with the Turbo PMAC PID/feed-forward/notch filter.

    Attributes:
        name: Model name, e.g. ``"TurboPMAC2"``.
        line: Product line as sold.
        description: What the controller is.
        n_motors: Motors the Turbo firmware addresses (I-variables I100 .. I3299).
        clock_defaults: Default ``(I7000, I7001, I7002)``: MaxPhase frequency control, phase
            clock divider, servo clock divider.
    """

    name: str
    line: str
    description: str
    n_motors: int
    clock_defaults: tuple[int, int, int]

    family: ClassVar[str] = "pmac"

    @property
    def servo_period_ticks(self) -> int:
        """Default servo interrupt period in master-clock cycles (117.9648 MHz)."""
        i7000, i7001, i7002 = self.clock_defaults
        return (2 * i7000 + 3) * (i7001 + 1) * (i7002 + 1)

    @property
    def sample_time_us(self) -> float:
        """Default servo period in microseconds (442.74 us for the factory clocks)."""
        return self.servo_period_ticks * 1e6 / MASTER_CLOCK_HZ


# Both models run the same Turbo firmware and filter. The Turbo PMAC2 clock defaults are [M]
# (chip-facts section 2); that the Geo Brick LV ships with the same ones is [A].
CHIP_MODELS: dict[str, PMACChipModel] = {
    m.name: m
    for m in [
        PMACChipModel(
            "TurboPMAC2",
            "Turbo PMAC2",
            "Turbo PMAC2 controller (PMAC2-style Servo ICs), up to 32 motors",
            32,
            (6527, 0, 3),
        ),
        PMACChipModel(
            "GeoBrickLV",
            "Geo Brick LV",
            "Geo Brick LV integrated controller and low-voltage drive (Turbo PMAC2 inside)",
            32,
            (6527, 0, 3),
        ),
    ]
}


def get_model(name: str) -> PMACChipModel:
    """Return the chip model called ``name`` (case-insensitive), or raise with close matches."""
    if isinstance(name, PMACChipModel):
        return name
    return CHIP_MODELS[resolve_name(name, CHIP_MODELS, "PMAC chip model")]


# --------------------------------------------------------------------------------------
# Assumptions: every point of the arithmetic that no source settles. Ids match the spec.
# --------------------------------------------------------------------------------------

ASSUMPTION_CHOICES: dict[str, tuple[str, ...]] = {
    # field name: (default, alternatives...)
    "rounding": ("floor", "trunc"),  # PMAC-A1
    "integral_timing": ("previous", "current"),  # PMAC-A2
    "integrator_input": ("deadband", "big_step"),  # PMAC-A3
    "anti_windup": ("hold_growth", "freeze"),  # PMAC-A4
    "notch_position": ("after_kp", "before_kp"),  # PMAC-A5
    "notch_form": ("df1", "df2"),  # PMAC-A6
    "deadband_outside": ("offset", "plain"),  # PMAC-A7
    "friction_order": ("before_limit", "after_limit"),  # PMAC-A8
    "bias_order": ("limit_then_bias", "bias_then_limit"),  # PMAC-A9
    "velocity_words": ("s24", "s32"),  # PMAC-A10
    "trip_action": ("kill", "kill_bias", "flag_only"),  # PMAC-A11
    "trip_compare": ("greater", "greater_equal"),  # PMAC-A12
    "first_cycle": ("actual", "commanded"),  # PMAC-A13
    "loop_latency": ("phase_edge", "same_tick", "half_period", "full_period"),  # PMAC-A14
}

ASSUMPTION_IDS: dict[str, str] = {
    name: f"PMAC-A{i}" for i, name in enumerate(ASSUMPTION_CHOICES, start=1)
}


@dataclasses.dataclass(frozen=True)
class PMACAssumptions(AssumptionSet):
    """Switches for every behaviour of the Turbo PMAC filter that no source settles.

    Each field is one assumption of ``docs/chips/pmac.md`` (PMAC-A1 ... PMAC-A14); the default
    is the first choice listed there. A trace from real hardware can decide between them.

    Attributes:
        rounding: PMAC-A1. How every right shift (division by a power of two) rounds:
            ``"floor"`` (arithmetic shift) or ``"trunc"`` (toward zero). Taking the DAC value
            from bits 8..23 of the output word is a bit selection and always floors.
        integral_timing: PMAC-A2. ``"previous"``: the integral term of cycle n uses the errors
            of cycles before n (the manual's IE(n) = sum of FE(j), j < n); the integrator takes
            FE(n) after the output. ``"current"``: FE(n) is added before the output.
        integrator_input: PMAC-A3. What the integrator sums: ``"deadband"`` (the big-step and
            deadband stage's output, as in the manual's block diagram) or ``"big_step"`` (the
            error after the big-step limit, before the deadband).
        anti_windup: PMAC-A4. While the output is limited by Ixx69: ``"hold_growth"`` drops an
            increment that would grow the integrator's magnitude; ``"freeze"`` drops every
            increment.
        notch_position: PMAC-A5. ``"after_kp"``: the notch filters the 24-bit output word
            after the Ixx30 multiplication; ``"before_kp"``: it filters the servo sum (a
            32-bit word) before it.
        notch_form: PMAC-A6. ``"df1"`` (direct form I) or ``"df2"`` (direct form II).
        deadband_outside: PMAC-A7. Outside the deadband: ``"offset"`` (the error is shifted
            by Ixx64*band/16 so the command is continuous and the gain approaches Ixx30) or
            ``"plain"`` (the error is used unchanged).
        friction_order: PMAC-A8. The friction feed-forward Ixx68 is added ``"before_limit"``
            or ``"after_limit"`` (Ixx69).
        bias_order: PMAC-A9. ``"limit_then_bias"``: ``sat16(limit(x) + Ixx29)``;
            ``"bias_then_limit"``: ``limit(x + Ixx29)``. The default is sourced [M]: the
            Software Reference adds Ixx29 "to the output command value before it is written
            to the command output register", the last step; the switch stays for traces.
        velocity_words: PMAC-A10. Width of the commanded velocity, commanded acceleration and
            velocity-feedback words in internal units: ``"s24"`` or ``"s32"``.
        trip_action: PMAC-A11. On a fatal following error: ``"kill"`` (output 0 from that
            cycle on), ``"kill_bias"`` (output Ixx29 from then on) or ``"flag_only"`` (the trip
            is latched, the filter keeps driving).
        trip_compare: PMAC-A12. The fatal following error condition: ``"greater"``
            (|FE| > limit) or ``"greater_equal"`` (|FE| >= limit).
        first_cycle: PMAC-A13. The previous commanded position at the first cycle after
            reset: ``"actual"`` (the loop closes with the commanded position at the actual
            one) or ``"commanded"`` (the commanded position itself: no commanded velocity in
            the first cycle).
        loop_latency: PMAC-A14. Time from the encoder sample to the new command reaching the
            amplifier (the old command holds until then): ``"phase_edge"``, the next phase
            clock edge, one phase period = servo period / (I7002 + 1) (110.7 us at the
            factory clocks); ``"same_tick"``; ``"half_period"``; ``"full_period"`` (of the
            filter's period).
    """

    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = ASSUMPTION_CHOICES
    IDS: ClassVar[dict[str, str]] = ASSUMPTION_IDS

    rounding: str = "floor"
    integral_timing: str = "previous"
    integrator_input: str = "deadband"
    anti_windup: str = "hold_growth"
    notch_position: str = "after_kp"
    notch_form: str = "df1"
    deadband_outside: str = "offset"
    friction_order: str = "before_limit"
    bias_order: str = "limit_then_bias"
    velocity_words: str = "s24"
    trip_action: str = "kill"
    trip_compare: str = "greater"
    first_cycle: str = "actual"
    loop_latency: str = "phase_edge"


A_INDEX: dict[str, int] = PMACAssumptions.index()
"""Index of each assumption in :meth:`PMACAssumptions.to_array`, for the kernel."""

# --------------------------------------------------------------------------------------
# Registers
# --------------------------------------------------------------------------------------


def _ivar(number: int) -> dict[str, Spelling]:
    """The I-variable of a register (dialect ``"ivar"``): the suffix ``xx`` of ``Ixx30``
    (below 100, per motor) or the full number of a global I-variable (``7000``)."""
    return {"ivar": Spelling(f"Ixx{number:02d}" if number < 100 else f"I{number}", number)}


_GAIN = dict(width="s24", log=True, source="M")
_COEF = dict(
    width="s24 (1 sign, 1 integer, 22 fraction bits)", unit="1/2^22", source="M", tunable=True
)

TABLE = RegisterTable(
    "pmac",
    [
        Register(
            "position_loop_scale",
            0,
            U23_MAX,
            96,
            "u23",
            tunable=False,
            unit="factor",
            doc="Ixx08: position scale; internal position resolution is 1/(32*Ixx08) count",
            spelling=_ivar(8),
        ),
        Register(
            "velocity_loop_scale",
            0,
            U23_MAX,
            96,
            "u23",
            tunable=False,
            unit="factor",
            doc="Ixx09: velocity-loop scale on the actual-velocity feedback of Ixx31",
            spelling=_ivar(9),
        ),
        Register(
            "fatal_following_error_limit",
            0,
            U23_MAX,
            32000,
            "u23",
            tunable=False,
            unit="1/16 count",
            doc="Ixx11: the motor is killed when the following error exceeds it; 0 disables",
            source="M",  # range and default: Delta Tau's public Turbo PMAC quick reference
            spelling=_ivar(11),
        ),
        Register(
            "output_bias",
            S16_MIN,
            S16_MAX,
            0,
            "s16",
            tunable=False,
            unit="DAC bits",
            doc="Ixx29: offset added to the output command (PMAC-A9)",
            spelling=_ivar(29),
        ),
        Register(
            "proportional_gain",
            S24_MIN,
            S24_MAX,
            2000,
            unit="Ixx08/2^19 DAC bits/count",
            doc="Ixx30: proportional gain, and the overall loop gain multiplying every term",
            **_GAIN,
            spelling=_ivar(30),
        ),
        Register(
            "derivative_gain",
            S24_MIN,
            S24_MAX,
            1280,
            unit="Ixx30*Ixx09/2^26 DAC bits/(count/cycle)",
            doc="Ixx31: derivative gain on the actual velocity",
            **_GAIN,
            spelling=_ivar(31),
        ),
        Register(
            "velocity_ff",
            S24_MIN,
            S24_MAX,
            1280,
            unit="Ixx30*Ixx08/2^26 DAC bits/(count/cycle)",
            doc="Ixx32: velocity feed-forward gain on the commanded velocity",
            **_GAIN,
            spelling=_ivar(32),
        ),
        Register(
            "integral_gain",
            0,
            U23_MAX,
            0,
            unit="Ixx30*Ixx08/2^42 DAC bits/(count*cycle)",
            doc="Ixx33: integral gain; it scales the integrator's input",
            **{**_GAIN, "width": "u23"},
            spelling=_ivar(33),
        ),
        Register(
            "integration_mode",
            0,
            1,
            1,
            "u1 flag",
            tunable=False,
            unit="flag",
            doc="Ixx34: 1 integrates only while the commanded velocity is zero; 0 always",
            spelling=_ivar(34),
        ),
        Register(
            "acceleration_ff",
            S24_MIN,
            S24_MAX,
            0,
            unit="Ixx30*Ixx08/2^26 DAC bits/(count/cycle^2)",
            doc="Ixx35: acceleration feed-forward gain on the commanded acceleration",
            **_GAIN,
            spelling=_ivar(35),
        ),
        Register(
            "notch_n1",
            S24_MIN,
            S24_MAX,
            0,
            doc="Ixx36: notch numerator n1",
            **_COEF,
            spelling=_ivar(36),
        ),
        Register(
            "notch_n2",
            S24_MIN,
            S24_MAX,
            0,
            doc="Ixx37: notch numerator n2",
            **_COEF,
            spelling=_ivar(37),
        ),
        Register(
            "notch_d1",
            S24_MIN,
            S24_MAX,
            0,
            doc="Ixx38: notch denominator d1",
            **_COEF,
            spelling=_ivar(38),
        ),
        Register(
            "notch_d2",
            S24_MIN,
            S24_MAX,
            0,
            doc="Ixx39: notch denominator d2",
            **_COEF,
            spelling=_ivar(39),
        ),
        Register(
            "servo_cycle_extension",
            0,
            255,
            0,
            "u8",
            tunable=False,
            unit="servo interrupts - 1",
            doc="Ixx60: the filter runs every Ixx60+1 servo interrupts",
            source="M",  # range and default: Delta Tau's public Turbo PMAC quick reference
            spelling=_ivar(60),
        ),
        Register(
            "integration_limit",
            S24_MIN,
            S24_MAX,
            4_194_304,
            "s24",
            tunable=False,
            unit="1/16 count of integrator output",
            doc="Ixx63: bound on the integrator output; 0 forces it to zero; < 0 also trips",
            spelling=_ivar(63),
        ),
        Register(
            "deadband_gain",
            S16_MIN,
            S16_MAX,
            0,
            "s16",
            tunable=False,
            unit="1/16",
            doc="Ixx64: gain inside the deadband is (16+Ixx64)/16 of the nominal",
            spelling=_ivar(64),
        ),
        Register(
            "deadband_size",
            0,
            U15_MAX,
            16,
            "u15",
            tunable=False,
            unit="1/16 count",
            doc="Ixx65: half-width of the deadband",
            spelling=_ivar(65),
        ),
        Register(
            "big_step_limit",
            0,
            U23_MAX,
            4_194_304,
            "u23",
            tunable=False,
            unit="1/16 count",
            doc="Ixx67: largest following error let into the filter",
            spelling=_ivar(67),
        ),
        Register(
            "friction_ff",
            0,
            U15_MAX,
            0,
            "u15",
            unit="DAC bits",
            doc="Ixx68: added with the sign of the commanded velocity (PMAC-A8)",
            spelling=_ivar(68),
        ),
        Register(
            "output_limit",
            0,
            U15_MAX,
            20480,
            "u15",
            tunable=False,
            unit="DAC bits",
            doc="Ixx69: bound on the magnitude of the output command",
            spelling=_ivar(69),
        ),
        Register(
            "max_phase_frequency_control",
            0,
            U15_MAX,
            6527,
            "u15",
            tunable=False,
            unit="master clock cycles",
            doc="I7000: MaxPhase clock = 117.9648 MHz / (2*I7000+3)",
            source="A",
            spelling=_ivar(7000),
            controller_wide=True,
        ),
        Register(
            "phase_clock_divider",
            0,
            15,
            0,
            "u4",
            tunable=False,
            unit="MaxPhase cycles - 1",
            doc="I7001: phase clock = MaxPhase clock / (I7001+1)",
            source="A",
            spelling=_ivar(7001),
            controller_wide=True,
        ),
        Register(
            "servo_clock_divider",
            0,
            15,
            3,
            "u4",
            tunable=False,
            unit="phase cycles - 1",
            doc="I7002: servo clock = phase clock / (I7002+1)",
            source="A",
            spelling=_ivar(7002),
            controller_wide=True,
        ),
    ],
)

FIELDS: tuple[str, ...] = TABLE.names
"""Every register of a PMACParams, in kernel-array order."""

P_INDEX: dict[str, int] = TABLE.index()

I_VARIABLES: dict[str, int] = {name: sp.code for name, sp in TABLE.spellings("ivar").items()}
"""I-variable of each register: the suffix ``xx`` of ``Ixx30`` (below 100, per motor) or the
full number of a global I-variable (``7000``)."""

GLOBAL_FIELDS: tuple[str, ...] = tuple(f for f, n in I_VARIABLES.items() if n >= 100)
"""Registers that are global I-variables (the servo clock), the same for every motor."""

COEFFICIENT_FIELDS: tuple[str, ...] = ("notch_n1", "notch_n2", "notch_d1", "notch_d2")
"""Registers written as decimal coefficients (-2.0 .. +2.0) in I-variable files."""


def ivar_name(field: str, motor: int) -> str:
    """The I-variable of register ``field`` for ``motor``: ``ivar_name("proportional_gain", 1)``
    is ``"I130"``; global registers ignore the motor (``"I7000"``)."""
    n = I_VARIABLES[field]
    return f"I{n}" if n >= 100 else f"I{motor * 100 + n}"


def coefficient_value(raw: int) -> Fraction:
    """The exact value of a 24-bit notch coefficient word: ``raw / 2^22``."""
    return Fraction(int(raw), 1 << COEFFICIENT_FRACTION_BITS)


def coefficient_raw(value: float | Fraction | str) -> int:
    """The 24-bit word nearest to a coefficient value (ties away from zero).

    Args:
        value: The coefficient, -2.0 .. +2.0 (a float, a Fraction or a decimal string).

    Returns:
        ``round(value * 2^22)``, not range-checked (the parameter set checks it).
    """
    x = Fraction(value) * (1 << COEFFICIENT_FRACTION_BITS)
    sign = -1 if x < 0 else 1
    return sign * int(abs(x) + Fraction(1, 2))


def parameter_space(model: str | PMACChipModel) -> ParameterSpace:
    """The legal registers of one PMAC model (the clock defaults are the model's)."""
    m = get_model(model)
    defaults = zip(GLOBAL_FIELDS, m.clock_defaults, strict=True)
    return TABLE.space(m.name, {name: {"default": value} for name, value in defaults})


@dataclasses.dataclass(frozen=True)
class PMACParams(RegisterSet, table=TABLE, get_model=get_model, space=parameter_space):
    """A complete, legal parameter set for one motor of a Turbo PMAC controller.

    Field names say what each I-variable does; :data:`I_VARIABLES` maps them one to one to the
    controller's numbers (``proportional_gain`` is Ixx30). Construction validates every field
    against the legal ranges and raises :class:`ParameterError` naming the parameter, the
    value and the range; nothing is clamped or rolled over.

    Attributes:
        model: Chip model name (``"TurboPMAC2"`` or ``"GeoBrickLV"``).
        position_loop_scale: Ixx08, 0 .. 8,388,607.
        velocity_loop_scale: Ixx09, 0 .. 8,388,607.
        fatal_following_error_limit: Ixx11, 1/16 count, 0 .. 8,388,607 (0 disables).
        output_bias: Ixx29, DAC bits, -32,768 .. 32,767.
        proportional_gain, derivative_gain, velocity_ff, acceleration_ff: Ixx30, Ixx31,
            Ixx32, Ixx35, signed 24-bit, -8,388,608 .. 8,388,607.
        integral_gain: Ixx33, 0 .. 8,388,607.
        integration_mode: Ixx34, 0 or 1.
        notch_n1, notch_n2, notch_d1, notch_d2: Ixx36 .. Ixx39 as raw 24-bit words,
            -8,388,608 .. 8,388,607, meaning ``raw / 2^22`` (-2.0 .. +2.0).
        servo_cycle_extension: Ixx60, 0 .. 255.
        integration_limit: Ixx63, -8,388,608 .. 8,388,607.
        deadband_gain: Ixx64, -32,768 .. 32,767.
        deadband_size: Ixx65, 1/16 count, 0 .. 32,767.
        big_step_limit: Ixx67, 1/16 count, 0 .. 8,388,607.
        friction_ff: Ixx68, DAC bits, 0 .. 32,767.
        output_limit: Ixx69, DAC bits, 0 .. 32,767.
        max_phase_frequency_control: I7000, 0 .. 32,767. ``None``: the model's default.
        phase_clock_divider: I7001, 0 .. 15. ``None``: the model's default.
        servo_clock_divider: I7002, 0 .. 15. ``None``: the model's default.
    """

    model: str = "TurboPMAC2"
    position_loop_scale: int = 96
    velocity_loop_scale: int = 96
    fatal_following_error_limit: int = 32000
    output_bias: int = 0
    proportional_gain: int = 2000
    derivative_gain: int = 1280
    velocity_ff: int = 1280
    integral_gain: int = 0
    integration_mode: int = 1
    acceleration_ff: int = 0
    notch_n1: int = 0
    notch_n2: int = 0
    notch_d1: int = 0
    notch_d2: int = 0
    servo_cycle_extension: int = 0
    integration_limit: int = 4_194_304
    deadband_gain: int = 0
    deadband_size: int = 16
    big_step_limit: int = 4_194_304
    friction_ff: int = 0
    output_limit: int = 20480
    max_phase_frequency_control: int | None = None
    phase_clock_divider: int | None = None
    servo_clock_divider: int | None = None

    def __post_init__(self) -> None:
        self._check_registers()

    @property
    def servo_period_ticks(self) -> int:
        """Servo interrupt period in master-clock cycles: (2*I7000+3)*(I7001+1)*(I7002+1)."""
        return (
            (2 * self.max_phase_frequency_control + 3)
            * (self.phase_clock_divider + 1)
            * (self.servo_clock_divider + 1)
        )

    @property
    def sample_time_ticks(self) -> int:
        """Filter period in master-clock cycles: the servo period times (Ixx60+1)."""
        return self.servo_period_ticks * (self.servo_cycle_extension + 1)

    @property
    def servo_period_s(self) -> float:
        """Servo interrupt period in seconds (442.74 us for the factory clocks)."""
        return self.servo_period_ticks / MASTER_CLOCK_HZ

    @property
    def sample_time_s(self) -> float:
        """The filter's period in seconds: the servo period times (Ixx60+1)."""
        return self.sample_time_ticks / MASTER_CLOCK_HZ

    @property
    def sample_time_us(self) -> float:
        """The filter's period in microseconds."""
        return self.sample_time_ticks * 1e6 / MASTER_CLOCK_HZ

    @property
    def motor_limit(self) -> int:
        """Largest output magnitude the set allows: Ixx69, in 16-bit DAC bits."""
        return self.output_limit

    def coefficients(self) -> tuple[Fraction, Fraction, Fraction, Fraction]:
        """Ixx36..Ixx39 as exact values ``(n1, n2, d1, d2)``."""
        n1, n2, d1, d2 = (coefficient_value(getattr(self, f)) for f in COEFFICIENT_FIELDS)
        return n1, n2, d1, d2
