"""PMD Navigator / Pilot / Magellan: chip models, assumption switches and parameter sets.

Every number here is also in ``docs/chips/pmd.md``; ``tests/chips/test_pmd_docs.py`` checks
that the spec's tables match this module.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

from servogym.chips._assumptions import AssumptionSet
from servogym.chips._registers import Register, RegisterSet, RegisterTable, Spelling
from servogym.chips._space import ParameterError, ParameterSpace, resolve_name

SPEC_VERSION = "pmd-spec-2"
"""Version of ``docs/chips/pmd.md`` the filter implements; written into exported files."""

U16_MAX = 32767
S16_MIN, S16_MAX = -32768, 32767
U31_MAX = 2_147_483_647


@dataclasses.dataclass(frozen=True)
class PMDChipModel:
    """One PMD servo chip model.

    Attributes:
        name: Model name as sold, e.g. ``"MC2100"``.
        line: Product line: ``"Navigator"``, ``"Pilot"`` or ``"Magellan"``.
        description: What the chip drives.
        n_axes: Largest number of axes in the model series.
        sample_time_us: Default servo period for one enabled axis, in microseconds [A].
        min_sample_time_us: Shortest legal servo period for one enabled axis, in microseconds.
        has_biquads: Whether the position loop has the two optional biquad stages.
        host_interface: ``"navigator"`` (one Set command per register, opcodes of the
            Navigator/Pilot family) or ``"magellan"`` (``SetPositionLoop`` with parameter
            numbers).
        kout_max: Largest legal Kout: 32767 in the Navigator/Pilot manual's table [M];
            65535 on Magellan, whose public C-Motion code writes PositionLoopKout 65535 [C].
    """

    name: str
    line: str
    description: str
    n_axes: int
    sample_time_us: int
    min_sample_time_us: int
    has_biquads: bool
    host_interface: str
    kout_max: int = 32767

    family: ClassVar[str] = "pmd"


# One table for every per-model difference. Sample times: a Navigator host comment gives
# "4 axis * 154 us/axis" [C]; Pilot is the one-axis Navigator [A]; Magellan's 51.2 us/axis is
# rounded up to a whole microsecond because SetSampleTime takes microseconds [A].
CHIP_MODELS: dict[str, PMDChipModel] = {
    m.name: m
    for m in [
        PMDChipModel(
            "MC2100", "Navigator", "DC brush servo, 1-4 axes", 4, 154, 154, False, "navigator"
        ),
        PMDChipModel(
            "MC2300", "Navigator", "brushless DC servo, 1-4 axes", 4, 154, 154, False, "navigator"
        ),
        PMDChipModel(
            "MC2800",
            "Navigator",
            "DC brush and brushless servo, 1-4 axes",
            4,
            154,
            154,
            False,
            "navigator",
        ),
        PMDChipModel("MC3110", "Pilot", "DC brush servo, 1 axis", 1, 154, 154, False, "navigator"),
        PMDChipModel(
            "MC3310", "Pilot", "brushless DC servo, 1 axis", 1, 154, 154, False, "navigator"
        ),
        PMDChipModel(
            "MC58000",
            "Magellan",
            "DC brush, brushless and step servo, 1-4 axes",
            4,
            52,
            52,
            True,
            "magellan",
            kout_max=65535,
        ),
    ]
}


def get_model(name: str) -> PMDChipModel:
    """Return the chip model called ``name`` (case-insensitive), or raise with close matches."""
    return CHIP_MODELS[resolve_name(name, CHIP_MODELS, "PMD chip model")]


# --------------------------------------------------------------------------------------
# Assumptions: every point of the arithmetic that no source settles. Ids match the spec.
# --------------------------------------------------------------------------------------

ASSUMPTION_CHOICES: dict[str, tuple[str, ...]] = {
    # field name: (default, alternatives...)
    "rounding": ("floor", "trunc"),  # PMD-A1
    "integral_shift": ("8", "0"),  # PMD-A2
    "feedforward_input": ("integer", "fraction"),  # PMD-A3
    "kout_scales_feedforward": ("yes", "no"),  # PMD-A4
    "bias_order": ("bias_then_limit", "limit_then_bias"),  # PMD-A5
    "error_saturation": ("none", "sat16"),  # PMD-A6
    "derivative_saturation": ("sat16", "none"),  # PMD-A7
    "derivative_mode": ("sample_difference", "cycle_difference"),  # PMD-A8
    "accumulator": ("sat32", "sat48"),  # PMD-A9
    "motion_error": ("stop", "flag_only"),  # PMD-A10
    "error_limit_compare": ("greater", "greater_equal"),  # PMD-A11
    "biquad_format": ("q14", "q15"),  # PMD-A12
    "loop_latency": ("axis_slot", "same_tick", "half_period", "full_period"),  # PMD-A13
}

ASSUMPTION_IDS: dict[str, str] = {
    name: f"PMD-A{i}" for i, name in enumerate(ASSUMPTION_CHOICES, start=1)
}


@dataclasses.dataclass(frozen=True)
class PMDAssumptions(AssumptionSet):
    """Switches for every behaviour of the PMD filter that no source settles.

    Each field is one assumption of ``docs/chips/pmd.md`` (PMD-A1 ... PMD-A13); the default is
    the first choice listed there. A trace from real hardware can decide between them.

    Attributes:
        rounding: PMD-A1. How every right shift (division by a power of two) rounds:
            ``"floor"`` (arithmetic shift) or ``"trunc"`` (toward zero).
        integral_shift: PMD-A2. The integral term is ``Ki * I >> s``; ``"8"`` or ``"0"``.
        feedforward_input: PMD-A3. Whether the 16.16 commanded velocity and acceleration
            enter as their integer part (``"integer"``) or with their 16 fractional bits
            (``"fraction"``: ``Kvff * V >> 16``).
        kout_scales_feedforward: PMD-A4. ``"yes"``: Kout scales the whole sum; ``"no"``: the
            feed-forward terms are added after the Kout scaling.
        bias_order: PMD-A5. ``"bias_then_limit"``: ``clamp(Y + bias, ±limit)``;
            ``"limit_then_bias"``: ``sat16(clamp(Y, ±limit) + bias)``.
        error_saturation: PMD-A6. ``"none"``: the error is the 32-bit wrapped difference;
            ``"sat16"``: it is saturated to a signed 16-bit value before the filter.
        derivative_saturation: PMD-A7. ``"sat16"``: the derivative difference is saturated
            to signed 16 bits (GetDerivative returns 16 bits [C]); ``"none"``.
        derivative_mode: PMD-A8. ``"sample_difference"``: every DerivativeTime cycles,
            D = E now minus E at the previous derivative sample; ``"cycle_difference"``: every
            DerivativeTime cycles, D = E now minus E one cycle ago. D is held in between.
        accumulator: PMD-A9. Saturation of the filter sum before the Kout multiplication:
            ``"sat32"`` or ``"sat48"`` (signed).
        motion_error: PMD-A10. What the chip does when the error exceeds the position-error
            limit: ``"stop"`` (motor command 0 from that cycle on, as with auto-stop enabled)
            or ``"flag_only"`` (the event is latched, the filter keeps driving).
        error_limit_compare: PMD-A11. The trip condition: ``"greater"`` (|E| > limit) or
            ``"greater_equal"`` (|E| >= limit).
        biquad_format: PMD-A12 (MC58000 only). Fractional bits of the biquad coefficients
            B0..A2 and of the stage gain K: ``"q14"`` or ``"q15"``.
        loop_latency: PMD-A13. Time from the encoder sample to the new motor command
            reaching the amplifier (the old command holds until then): ``"axis_slot"``, one
            per-axis time slot (the model's minimum sample time, at most the period: a full
            period for one axis at the minimum cycle); ``"same_tick"`` (no latency);
            ``"half_period"``; ``"full_period"``.
    """

    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = ASSUMPTION_CHOICES
    IDS: ClassVar[dict[str, str]] = ASSUMPTION_IDS

    rounding: str = "floor"
    integral_shift: str = "8"
    feedforward_input: str = "integer"
    kout_scales_feedforward: str = "yes"
    bias_order: str = "bias_then_limit"
    error_saturation: str = "none"
    derivative_saturation: str = "sat16"
    derivative_mode: str = "sample_difference"
    accumulator: str = "sat32"
    motion_error: str = "stop"
    error_limit_compare: str = "greater"
    biquad_format: str = "q14"
    loop_latency: str = "axis_slot"


# Index of each assumption in PMDAssumptions.to_array(), for the kernel.
A_INDEX: dict[str, int] = PMDAssumptions.index()

# --------------------------------------------------------------------------------------
# Registers
# --------------------------------------------------------------------------------------


def _nav(rank: int, command: str, opcode: int, width: str) -> Spelling:
    """A Navigator/Pilot Set command: its export position, name, opcode and data width."""
    return Spelling(command, opcode, width, rank)


def _loop(number: int, enum: str) -> Spelling:
    """A Magellan ``SetPositionLoop`` parameter: number and C-Motion enum (data: s32)."""
    return Spelling(enum, number, "s32", number)


_GAIN = dict(width="u16 (15 bits used)", log=True, unit="gain")
_COEF = dict(width="s16", unit="1/2^14 (PMD-A12)", source="A", tunable=False)


def _biquad_rows(stage: int) -> list[Register]:
    p = f"biquad{stage}_"
    first = 8 + 7 * (stage - 1)

    def loop(i: int, part: str) -> dict[str, Spelling]:
        return {"magellan_loop": _loop(first + i, f"PMDPositionLoopBiquad{stage}{part}")}

    return [
        Register(
            p + "enable", 0, 1, 0, "u16 flag", tunable=False, unit="flag",
            doc=f"Biquad stage {stage} on (1) or bypassed (0)", source="C",
            spelling=loop(0, "Enable"),
        ),
        Register(p + "b0", S16_MIN, S16_MAX, 16384, doc="Numerator coefficient b0",
                 spelling=loop(1, "B0"), **_COEF),
        Register(p + "b1", S16_MIN, S16_MAX, 0, doc="Numerator coefficient b1",
                 spelling=loop(2, "B1"), **_COEF),
        Register(p + "b2", S16_MIN, S16_MAX, 0, doc="Numerator coefficient b2",
                 spelling=loop(3, "B2"), **_COEF),
        Register(p + "a1", S16_MIN, S16_MAX, 0, doc="Denominator coefficient a1",
                 spelling=loop(4, "A1"), **_COEF),
        Register(p + "a2", S16_MIN, S16_MAX, 0, doc="Denominator coefficient a2",
                 spelling=loop(5, "A2"), **_COEF),
        Register(
            p + "k", 0, U16_MAX, 16384, "u16 (15 bits used)", tunable=False,
            unit="1/2^14 (PMD-A12)", doc="Stage output gain", source="A",
            spelling=loop(6, "K"),
        ),
    ]  # fmt: skip


TABLE = RegisterTable(
    "pmd",
    [
        Register(
            "kp", 0, U16_MAX, 100, doc="Proportional gain",
            spelling={"navigator": _nav(0, "SetKp", 0x25, "u16"),
                      "magellan_loop": _loop(0, "PMDPositionLoopKp")},
            **_GAIN,
        ),
        Register(
            "ki", 0, U16_MAX, 80, doc="Integral gain; the term is ki * integral >> 8 (PMD-A2)",
            spelling={"navigator": _nav(1, "SetKi", 0x26, "u16"),
                      "magellan_loop": _loop(1, "PMDPositionLoopKi")},
            **_GAIN,
        ),
        Register(
            "kd", 0, U16_MAX, 400, doc="Derivative gain",
            spelling={"navigator": _nav(2, "SetKd", 0x27, "u16"),
                      "magellan_loop": _loop(3, "PMDPositionLoopKd")},
            **_GAIN,
        ),
        Register(
            "kvff", 0, U16_MAX, 0, doc="Velocity feed-forward gain on the commanded velocity",
            spelling={"navigator": _nav(3, "SetKvff", 0x2B, "u16"),
                      "magellan_loop": _loop(6, "PMDPositionLoopKvff")},
            **_GAIN,
        ),
        Register(
            "kaff", 0, U16_MAX, 0,
            doc="Acceleration feed-forward gain on the commanded acceleration",
            spelling={"navigator": _nav(4, "SetKaff", 0x93, "u16"),
                      "magellan_loop": _loop(7, "PMDPositionLoopKaff")},
            **_GAIN,
        ),
        Register(
            "kout", 0, U16_MAX, 13107, "u16 (15 bits used)", log=True, unit="1/65536",
            doc="Output scale: the filter result is multiplied by kout/65536",
            spelling={"navigator": _nav(7, "SetKout", 0x9E, "u16"),
                      "magellan_loop": _loop(5, "PMDPositionLoopKout")},
        ),
        Register(
            "integration_limit", 0, U31_MAX, 10000, "u32 (31 bits used)", log=True,
            unit="counts*cycles", doc="Bound on the magnitude of the accumulated error",
            spelling={"navigator": _nav(5, "SetIntegrationLimit", 0x95, "u32"),
                      "magellan_loop": _loop(2, "PMDPositionLoopIlimit")},
        ),
        Register(
            "derivative_time", 1, U16_MAX, 10, "u16 (15 bits used)", log=True, unit="cycles",
            doc="Derivative sampled every derivative_time cycles, held between", source="C",
            spelling={"navigator": _nav(6, "SetDerivativeTime", 0x9C, "u16"),
                      "magellan_loop": _loop(4, "PMDPositionLoopDerivativeTime")},
        ),
        Register(
            "bias", S16_MIN, S16_MAX, 0, "s16", unit="motor command",
            doc="DC motor offset added to the filter output",
            spelling={"navigator": _nav(8, "SetMotorBias", 0x0F, "s16"),
                      "magellan": Spelling("SetMotorBias", 0x0F, "s16")},
        ),
        Register(
            "motor_limit", 0, U16_MAX, U16_MAX, "u16 (15 bits used)", tunable=False,
            unit="motor command", doc="Bound on the magnitude of the motor command",
            spelling={"navigator": _nav(9, "SetMotorLimit", 0x06, "u16"),
                      "magellan": Spelling("SetMotorLimit", 0x06, "u16")},
        ),
        Register(
            "position_error_limit", 0, U31_MAX, 32767, "u32 (31 bits used)", tunable=False,
            unit="counts", doc="Motion error when the error magnitude exceeds it (PMD-A10, "
            "PMD-A11)", source="A",
            spelling={"navigator": _nav(10, "SetPositionErrorLimit", 0x97, "u32"),
                      "magellan": Spelling("SetPositionErrorLimit", 0x97, "u32")},
        ),
        # Range and default per model (PMDChipModel); Magellan's SetSampleTime is 0x3B, u32.
        Register(
            "sample_time_us", 1, 65535, 154, "u16", tunable=False, unit="us",
            doc="Servo period for one enabled axis", source="A",
            spelling={"navigator": _nav(11, "SetSampleTime", 0x38, "u16"),
                      "magellan": Spelling("SetSampleTime", 0x3B, "u32")},
            controller_wide=True,
        ),
        *_biquad_rows(1),
        *_biquad_rows(2),
    ],
)  # fmt: skip
"""Every register of the PMD family, in kernel-array order, with its Navigator/Pilot command
(``navigator``: name, opcode, data width, export position), its Magellan ``SetPositionLoop``
parameter (``magellan_loop``) or Magellan command (``magellan``); docs/chips/pmd-export.md."""

FIELDS: tuple[str, ...] = TABLE.names
"""Every register of a PMDParams, in kernel-array order."""

P_INDEX: dict[str, int] = TABLE.index()
BIQUAD_FIELDS: tuple[str, ...] = tuple(n for n in FIELDS if n.startswith("biquad"))


def parameter_space(model: str | PMDChipModel) -> ParameterSpace:
    """The legal registers of one PMD chip model (biquads only on MC58000)."""
    m = model if isinstance(model, PMDChipModel) else get_model(model)
    changes: dict[str, dict[str, Any]] = {
        "sample_time_us": {"low": m.min_sample_time_us, "default": m.sample_time_us}
    }
    if m.kout_max != U16_MAX:
        doc = TABLE["kout"].doc + " (65535 on Magellan, from its C-Motion code)"
        changes["kout"] = {"high": m.kout_max, "width": "u16", "source": "C", "doc": doc}
    return TABLE.space(m.name, changes, omit=() if m.has_biquads else BIQUAD_FIELDS)


@dataclasses.dataclass(frozen=True)
class PMDParams(RegisterSet, table=TABLE, get_model=get_model, space=parameter_space):
    """A complete, legal parameter set for one axis of a PMD chip.

    Field names are the chip's own register names (:data:`TABLE`). Construction validates
    every field against the chip model's legal ranges and raises :class:`ParameterError`
    naming the parameter, the value and the range; nothing is clamped.

    Attributes:
        model: Chip model name (``"MC2100"`` ... ``"MC58000"``).
        kp, ki, kd, kvff, kaff, kout: Filter gains, unsigned 16-bit, 0..32767.
        integration_limit: Bound on the error sum, 0..2,147,483,647.
        derivative_time: Derivative sample interval in cycles, 1..32767.
        bias: Motor bias, signed 16-bit, -32768..32767.
        motor_limit: Motor command limit, 0..32767.
        position_error_limit: Motion-error threshold in counts, 0..2,147,483,647.
        sample_time_us: Servo period in microseconds (model minimum .. 65535). ``None``
            selects the model's default.
        biquad1_* / biquad2_*: MC58000 biquad stages (enable 0/1, coefficients s16, k u16);
            on other models they must keep their defaults (bypassed).
    """

    model: str = "MC2100"
    kp: int = 100
    ki: int = 80
    kd: int = 400
    kvff: int = 0
    kaff: int = 0
    kout: int = 13107
    integration_limit: int = 10000
    derivative_time: int = 10
    bias: int = 0
    motor_limit: int = 32767
    position_error_limit: int = 32767
    sample_time_us: int | None = None
    biquad1_enable: int = 0
    biquad1_b0: int = 16384
    biquad1_b1: int = 0
    biquad1_b2: int = 0
    biquad1_a1: int = 0
    biquad1_a2: int = 0
    biquad1_k: int = 16384
    biquad2_enable: int = 0
    biquad2_b0: int = 16384
    biquad2_b1: int = 0
    biquad2_b2: int = 0
    biquad2_a1: int = 0
    biquad2_a2: int = 0
    biquad2_k: int = 16384

    def __post_init__(self) -> None:
        self._check_registers()

    def _absent(self, name: str, chip: Any, value: Any) -> ParameterError:
        default = self.TABLE[name].default
        return ParameterError(
            f"{name} exists only on models with biquad stages (MC58000); "
            f"{chip.name} has none, so {name} must stay {default}; got {name}={value!r}."
        )

    @property
    def sample_time_s(self) -> float:
        """Servo period in seconds."""
        return self.sample_time_us * 1e-6
