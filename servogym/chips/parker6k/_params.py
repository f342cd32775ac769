"""Parker Compumotor 6000-series servo (6250, 6K): models, assumptions and parameter sets.

Every gain is a decimal number on the controller (``SGP85``, ``SGV2.3``, ``SGP.5``); here
each is held as an integer count of its resolution (``sgp=8500`` is ``SGP85.00``), so the
arithmetic of ``docs/chips/parker6k.md`` is integer-exact. Every number in this module is
also in that spec; ``tests/chips/test_parker6k_docs.py`` checks that the tables match.
"""

from __future__ import annotations

import dataclasses
import difflib
import numbers
from collections.abc import Iterable, Mapping
from typing import Any, ClassVar

import numpy as np

from servogym.chips._assumptions import AssumptionSet
from servogym.chips._registers import Register, RegisterSet, RegisterTable, Spelling
from servogym.chips._space import ParameterError, ParameterSpace, ParamSpec, resolve_name

SPEC_VERSION = "parker6k-spec-2"
"""Version of ``docs/chips/parker6k.md`` the filter implements; written into exported files."""

GAIN_MAX = 9_999_999
"""Largest count of any gain register (99999.99 at two decimals, 999.9999 at four)."""
MAX_GAIN_SETS = 5
"""Stored gain sets a controller keeps (SGSET1 ... SGSET5) [M]."""
MAX_SWITCHES = 65_536
"""Longest SGENB schedule a parameter set may carry."""
TICK_MAX = 2**31 - 1
"""Largest servo tick an SGENB switch may be scheduled at."""
S32_MAX = 2**31 - 1

SSFR_PERIOD_US: dict[int, int] = {1: 330, 2: 185, 4: 160, 8: 150}
"""Servo sampling period in microseconds for each SSFR setting.

[A], from the table of the *APEX615n Installation Guide*, appendix A (same 6000-series servo
firmware): the 6250 guide has no such table, so that the 6250 and 6K use it is assumed.
"""
SSFR_FREQUENCY_HZ: dict[int, int] = {1: 3030, 2: 5405, 4: 6250, 8: 6667}
"""Servo sampling frequency as the manual's table prints it (rounded; the period is exact)."""
SSFR_TRAJECTORY_US: dict[int, int] = {r: r * t for r, t in SSFR_PERIOD_US.items()}
"""Motion trajectory update period: SSFR servo samples (330, 370, 640, 1200 us) [A: APEX615n]."""


@dataclasses.dataclass(frozen=True)
class Parker6kModel:
    """One 6000-series servo controller model.

    Attributes:
        name: Model name: ``"6250"`` or ``"6K"``.
        description: What the controller is.
        n_axes: Largest number of servo axes of the model series.
        default_ssfr: SSFR setting at power-up (servo sampling frequency ratio).
        axis_prefix: Whether the controller takes axis-prefixed commands (``1SGP10``); every
            model takes comma-separated axis fields (``SGP.5,.5``).
    """

    name: str
    description: str
    n_axes: int
    default_ssfr: int
    axis_prefix: bool

    family: ClassVar[str] = "parker6k"


# The 6250's SSFR4 default is stated for the OEM6250 [M: the APEX615n guide's SSFR table];
# the 6K's is assumed the same [A].
CHIP_MODELS: dict[str, Parker6kModel] = {
    m.name: m
    for m in [
        Parker6kModel("6250", "two-axis servo controller, +/-10 V analog outputs", 2, 4, False),
        Parker6kModel("6K", "6K2 ... 6K8 multi-axis controller, servo axes", 8, 4, True),
    ]
}


def get_model(name: str | Parker6kModel) -> Parker6kModel:
    """Return the model called ``name`` (case-insensitive), or raise with close matches."""
    if isinstance(name, Parker6kModel):
        return name
    if not isinstance(name, str):
        raise ParameterError(
            f"model must be a 6000-series model name, one of {', '.join(CHIP_MODELS)}; "
            f"got model={name!r} of type {type(name).__name__}."
        )
    return CHIP_MODELS[resolve_name(name, CHIP_MODELS, "Parker 6000-series model", n=2)]


# --------------------------------------------------------------------------------------
# Assumptions: every point of the arithmetic that no source settles. Ids match the spec.
# --------------------------------------------------------------------------------------

ASSUMPTION_CHOICES: dict[str, tuple[str, ...]] = {
    # field name: (default, alternatives...)
    "gain_unit": ("uV", "mV"),  # PK-A1
    "dac_bits": ("12", "16"),  # PK-A2
    "velocity_feedback": ("encoder", "error_rate"),  # PK-A3
    "integral_limit": ("accumulator", "output", "conditional"),  # PK-A4
    "offset_order": ("offset_then_saturate", "saturate_then_offset"),  # PK-A5
    "rounding": ("floor", "trunc"),  # PK-A6
    "smper_compare": ("greater", "greater_equal"),  # PK-A7
    "smper_zero": ("off", "limit"),  # PK-A8
    "loop_latency": ("full_period", "same_tick", "half_period"),  # PK-A9
    "integral_timing": ("current", "previous"),  # PK-A10
}

ASSUMPTION_IDS: dict[str, str] = {
    "gain_unit": "PK-A1",
    "dac_bits": "PK-A2",
    "velocity_feedback": "PK-A3",
    "integral_limit": "PK-A4",
    "offset_order": "PK-A5",
    "rounding": "PK-A6",
    "smper_compare": "PK-A7",
    "smper_zero": "PK-A8",
    "loop_latency": "PK-A9",
    "integral_timing": "PK-A10",
}
"""The spec's id of each switch (ids are never renumbered; the list order is the kernel's)."""


@dataclasses.dataclass(frozen=True)
class Parker6kAssumptions(AssumptionSet):
    """Switches for every behaviour of the 6000-series PIV&F filter that no source settles.

    Each field is one assumption of ``docs/chips/parker6k.md`` (PK-A1 ... PK-A10); the default
    is the first choice listed there. A trace from real hardware can decide between them.

    Attributes:
        gain_unit: PK-A1. Voltage unit of every gain: ``"uV"`` (SGP in uV/count, SGV and
            SGVF in uV/(count/s), SGI in uV/(count*s), SGAF in uV/(count/s^2)) or ``"mV"``
            (the same with mV: every gain 1000 times stronger).
        dac_bits: PK-A2. Resolution of the +/-10 V DAC: ``"12"`` or ``"16"`` bits. The
            motor command is the DAC code shifted to 16 bits (12 bits: steps of 16).
        velocity_feedback: PK-A3. ``"encoder"``: SGV multiplies the encoder velocity and the
            term is subtracted (damping); ``"error_rate"``: SGV multiplies the rate of change
            of the position error and the term is added.
        integral_limit: PK-A4. ``"accumulator"``: the integral term itself is accumulated
            (SGI * error * T each sample) and clamped to +-SGILIM; ``"output"``: the error sum
            is accumulated (32-bit, saturating) and only the term is clamped;
            ``"conditional"``: the error sum stops integrating while the term would exceed
            SGILIM.
        offset_order: PK-A5. ``"offset_then_saturate"``: DAC = sat(signal + SOFFS);
            ``"saturate_then_offset"``: DAC = sat(sat(signal, +-10 V) + SOFFS).
        rounding: PK-A6. Every division: ``"floor"`` (toward -infinity) or ``"trunc"``
            (toward zero).
        smper_compare: PK-A7. The trip condition: ``"greater"`` (|error| > SMPER) or
            ``"greater_equal"`` (|error| >= SMPER).
        smper_zero: PK-A8. ``"off"``: SMPER0 turns the error check off; ``"limit"``: SMPER0
            is a limit of 0 counts like any other.
        loop_latency: PK-A9. Time from the encoder sample to the new command reaching the
            drive (the old command holds until then): ``"full_period"`` (the DSP writes the
            output at the next servo sample), ``"same_tick"`` or ``"half_period"``.
        integral_timing: PK-A10. When the integrator takes this sample's error:
            ``"current"``: before the output is computed (the integral term of sample n
            includes E(n)); ``"previous"``: after it (the output of sample n uses the
            integrator as sample n-1 left it, and E(n) enters from sample n+1 on).
    """

    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = ASSUMPTION_CHOICES
    IDS: ClassVar[dict[str, str]] = ASSUMPTION_IDS

    gain_unit: str = "uV"
    dac_bits: str = "12"
    velocity_feedback: str = "encoder"
    integral_limit: str = "accumulator"
    offset_order: str = "offset_then_saturate"
    rounding: str = "floor"
    smper_compare: str = "greater"
    smper_zero: str = "off"
    loop_latency: str = "full_period"
    integral_timing: str = "current"


A_INDEX: dict[str, int] = Parker6kAssumptions.index()
"""Index of each assumption in :meth:`Parker6kAssumptions.to_array`, for the kernel."""


# --------------------------------------------------------------------------------------
# Registers
# --------------------------------------------------------------------------------------

GAIN_FIELDS: tuple[str, ...] = ("sgp", "sgi", "sgv", "sgvf", "sgaf")
"""The five gains of a gain set, in the order SGSET stores them."""


def _command(command: str, places: int) -> dict[str, Spelling]:
    """The controller command that sets a register (dialect ``"6000"``, the 6250 and 6K
    forms alike) and its decimal places: the register holds ``value * 10**places``."""
    return {"6000": Spelling(command, places)}


def _gain(
    name: str, places: int, default: int, unit: str, doc: str, default_note: str = ""
) -> Register:
    top = f"{GAIN_MAX // 10**places}.{'9' * places}"
    return Register(
        name,
        0,
        GAIN_MAX,
        default,
        f"u24, 0 .. {top} in steps of {10**-places:.{places}f}",
        log=True,
        unit=unit,
        doc=doc,
        source="A",
        default_note=default_note,
        spelling=_command(name.upper(), places),
    )


_EXAMPLE_DEFAULT = (
    "the 6250 guide's worked tuning example (SGP 85, SGV 2.3), not a controller default"
)

TABLE = RegisterTable(
    "parker6k",
    [
        _gain(
            "sgp",
            2,
            8500,
            "0.01 uV/count (PK-A1)",
            "Proportional gain SGP on the position error; 8500 is SGP85",
            _EXAMPLE_DEFAULT,
        ),
        _gain(
            "sgi",
            2,
            0,
            "0.01 uV/(count*s) (PK-A1)",
            "Integral gain SGI on the time integral of the position error",
        ),
        _gain(
            "sgv",
            2,
            230,
            "0.01 uV/(count/s) (PK-A1)",
            "Velocity feedback gain SGV on the encoder velocity (PK-A3); 230 is SGV2.3",
            _EXAMPLE_DEFAULT,
        ),
        _gain(
            "sgvf",
            2,
            0,
            "0.01 uV/(count/s) (PK-A1)",
            "Velocity feed-forward gain SGVF on the commanded velocity",
        ),
        _gain(
            "sgaf",
            4,
            0,
            "0.0001 uV/(count/s^2) (PK-A1)",
            "Acceleration feed-forward gain SGAF on the commanded acceleration",
        ),
        Register(
            "sgilim",
            0,
            10_000,
            10_000,
            "u14, 0 .. 10.000 V in steps of 0.001",
            tunable=False,
            unit="mV",
            doc="Integral windup limit SGILIM: bound on the integral term (PK-A4)",
            source="A",
            spelling=_command("SGILIM", 3),
        ),
        Register(
            "soffs",
            -10_000,
            10_000,
            0,
            "s15, -10.000 .. 10.000 V in steps of 0.001",
            tunable=False,
            unit="mV",
            doc="Control signal offset SOFFS added to the DAC output (PK-A5)",
            source="A",
            spelling=_command("SOFFS", 3),
        ),
        Register(
            "smper",
            0,
            S32_MAX,
            0,
            "u31",
            tunable=False,
            unit="counts",
            doc="Position error limit SMPER that shuts the drive down (PK-A7, PK-A8)",
            source="A",
            spelling=_command("SMPER", 0),
        ),
        # The default is the model's (Parker6kModel.default_ssfr).
        Register(
            "ssfr",
            1,
            8,
            4,
            "one of 1, 2, 4, 8",
            tunable=False,
            unit="ratio",
            doc="Servo sampling frequency ratio SSFR: servo period 330, 185, 160, 150 us "
            "(APEX615n guide's table)",
            source="A",
            spelling=_command("SSFR", 0),
            controller_wide=True,
        ),
    ],
)
"""Every flat register of the 6000-series family, in export and kernel order, with the
command that sets it and that command's decimal places (docs/chips/parker6k.md)."""

COMMANDS: dict[str, str] = {name: sp.text for name, sp in TABLE.spellings("6000").items()}
"""The controller command that sets each register."""

DECIMALS: dict[str, int] = {name: sp.code for name, sp in TABLE.spellings("6000").items()}
"""Decimal places of each command's value: a register holds ``value * 10**DECIMALS``."""

FIELDS: tuple[str, ...] = TABLE.names
"""Every flat register of a :class:`Parker6kParams`, in export order."""


def parameter_space(model: str | Parker6kModel) -> ParameterSpace:
    """The flat registers of one model: the active gains, the axis settings and SSFR.

    The stored gain sets (``sgset``) and the SGENB schedule (``sgenb``) are structured
    fields of :class:`Parker6kParams`, not registers of this space.
    """
    m = get_model(model)
    return TABLE.space(m.name, {"ssfr": {"default": m.default_ssfr}})


_GAIN_SPACE = {name: TABLE[name].spec() for name in GAIN_FIELDS}


def check_ssfr(value: int, context: str) -> int:
    if value not in SSFR_PERIOD_US:
        raise ParameterError(
            f"ssfr must be one of 1, 2, 4, 8 (SSFR1 330 us, SSFR2 185 us, SSFR4 160 us, "
            f"SSFR8 150 us; 1 <= ssfr <= 8) ({context}); got ssfr={value}."
        )
    return value


@dataclasses.dataclass(frozen=True)
class GainSet:
    """One set of PIV&F gains, as SGSET stores it (SGP, SGI, SGV, SGVF, SGAF) [M].

    Attributes:
        sgp, sgi, sgv, sgvf: Gains in steps of 0.01 (0 .. 9,999,999, i.e. up to 99999.99).
        sgaf: Gain in steps of 0.0001 (0 .. 9,999,999, i.e. up to 999.9999).

    The defaults SGP85 and SGV2.3 are the 6250 guide's worked tuning example, not values the
    controller powers up with.
    """

    sgp: int = 8500
    sgi: int = 0
    sgv: int = 230
    sgvf: int = 0
    sgaf: int = 0

    def __post_init__(self) -> None:
        for name in GAIN_FIELDS:
            object.__setattr__(self, name, _GAIN_SPACE[name].validate(getattr(self, name)))

    def to_dict(self) -> dict[str, int]:
        """The five gains by name."""
        return {n: getattr(self, n) for n in GAIN_FIELDS}

    def to_tuple(self) -> tuple[int, int, int, int, int]:
        """``(sgp, sgi, sgv, sgvf, sgaf)``."""
        return (self.sgp, self.sgi, self.sgv, self.sgvf, self.sgaf)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any], *, context: str = "") -> GainSet:
        """Build from a mapping of gain names; every gain must be given, no other name."""
        where = f" ({context})" if context else ""
        if not isinstance(values, Mapping):
            raise ParameterError(
                f"a gain set must be a GainSet or a mapping of {', '.join(GAIN_FIELDS)}"
                f"{where}; got {values!r} of type {type(values).__name__}."
            )
        for name in values:
            if name not in GAIN_FIELDS:
                close = difflib.get_close_matches(str(name), GAIN_FIELDS, n=2)
                hint = f" Did you mean {', '.join(close)}?" if close else ""
                raise ParameterError(
                    f"a gain set has the gains {', '.join(GAIN_FIELDS)}{where}; got an "
                    f"unknown name {name!r}.{hint}"
                )
        missing = [n for n in GAIN_FIELDS if n not in values]
        if missing:
            raise ParameterError(
                f"a gain set must give every gain{where}; missing {', '.join(missing)}."
            )
        return cls(**{n: values[n] for n in GAIN_FIELDS})


def _set_context(model: str, index: int) -> str:
    return f"{model}, stored gain set {index} (SGSET{index})"


def _check_gain_set(value: Any, index: int, model: str) -> GainSet:
    context = _set_context(model, index)
    if isinstance(value, GainSet):
        # Validate again with the set named in the message (the object may be tampered).
        for name in GAIN_FIELDS:
            _GAIN_SPACE[name].validate(getattr(value, name), context=context)
        return value
    if isinstance(value, Mapping):
        names = [n for n in GAIN_FIELDS if n in value]
        for name in names:
            _GAIN_SPACE[name].validate(value[name], context=context)
        return GainSet.from_dict(value, context=context)
    raise ParameterError(
        f"sgset[{index - 1}] must be a GainSet or a mapping of {', '.join(GAIN_FIELDS)} "
        f"({context}); got {value!r} of type {type(value).__name__}."
    )


def _check_int(value: Any, name: str, low: int, high: int, where: str) -> int:
    return ParamSpec(name, low, high, low, "integer").validate(value, context=where)


def _check_schedule(value: Any, n_sets: int, model: str) -> tuple[tuple[int, int], ...]:
    if isinstance(value, (str, bytes)) or not isinstance(value, Iterable):
        raise ParameterError(
            f"sgenb must be a sequence of (tick, set) pairs ({model}); got sgenb={value!r}."
        )
    entries = list(value)
    if len(entries) > MAX_SWITCHES:
        raise ParameterError(
            f"sgenb holds at most {MAX_SWITCHES} switches ({model}); got {len(entries)}."
        )
    out: list[tuple[int, int]] = []
    for i, entry in enumerate(entries):
        where = f"{model}, sgenb[{i}]"
        if isinstance(entry, (str, bytes)) or not isinstance(entry, Iterable):
            raise ParameterError(f"sgenb[{i}] must be a (tick, set) pair ({model}); got {entry!r}.")
        pair = list(entry)
        if len(pair) != 2:
            raise ParameterError(f"sgenb[{i}] must be a (tick, set) pair ({model}); got {entry!r}.")
        tick = _check_int(pair[0], "tick", 0, TICK_MAX, where)
        if n_sets == 0:
            raise ParameterError(
                f"sgenb[{i}] enables a stored gain set, but sgset is empty ({model}): store "
                f"the sets first (SGSET1 ... SGSET{MAX_GAIN_SETS})."
            )
        number = _check_int(pair[1], "set", 1, n_sets, f"{where}; the stored sets are 1..{n_sets}")
        if out and tick <= out[-1][0]:
            raise ParameterError(
                f"sgenb ticks must strictly increase ({model}); sgenb[{i}] has tick={tick} "
                f"after tick={out[-1][0]}."
            )
        out.append((tick, number))
    return tuple(out)


# Kernel array layout (Parker6kParams.to_array()).
P_PERIOD_US, P_SSFR, P_SGILIM, P_SOFFS, P_SMPER = 0, 1, 2, 3, 4
P_GAINS = 5
"""Gains of set s (0 = the active gains at reset, 1..5 = stored sets) start at P_GAINS + 5s."""
P_N_SETS = P_GAINS + 5 * (MAX_GAIN_SETS + 1)  # 35
P_N_SWITCHES = P_N_SETS + 1  # 36
P_SWITCHES = P_N_SWITCHES + 1  # 37: ticks[n], then sets[n]


@dataclasses.dataclass(frozen=True)
class Parker6kParams(RegisterSet, table=TABLE, get_model=get_model, space=parameter_space):
    """A complete, legal parameter set for one servo axis of a 6000-series controller.

    Field names are the controller's command names. Gains are integers in steps of their
    decimal resolution (``sgp=8500`` is ``SGP85``); construction validates every field and
    raises :class:`ParameterError` naming the parameter, the value and the range (and the
    stored set for a stored gain); nothing is clamped.

    Attributes:
        model: ``"6250"`` or ``"6K"``.
        sgp, sgi, sgv, sgvf, sgaf: The gains in force at reset (what TGAIN reports),
            0 .. 9,999,999 each (SGP/SGI/SGV/SGVF in 0.01, SGAF in 0.0001).
        sgilim: Integral windup limit in mV, 0 .. 10,000 (0 .. 10.000 V).
        soffs: Control signal offset in mV, -10,000 .. 10,000.
        smper: Position error limit in counts, 0 .. 2,147,483,647 (0: PK-A8).
        ssfr: Servo sampling frequency ratio, one of 1, 2, 4, 8; ``None`` selects the
            model's default (4).
        sgset: The stored gain sets 1..len (SGSET1 ...), at most 5 :class:`GainSet`.
        sgenb: Gain-set switches during a move: ``(tick, set)`` pairs, ticks strictly
            increasing in 0 .. 2,147,483,647 (servo samples since the filter's reset), set in
            1 .. len(sgset). From that tick on, the stored set's gains are in force.
    """

    model: str = "6250"
    sgp: int = 8500
    sgi: int = 0
    sgv: int = 230
    sgvf: int = 0
    sgaf: int = 0
    sgilim: int = 10_000
    soffs: int = 0
    smper: int = 0
    ssfr: int | None = None
    sgset: tuple[GainSet, ...] = ()
    sgenb: tuple[tuple[int, int], ...] = ()

    def __post_init__(self) -> None:
        chip, _space = self._check_registers()
        check_ssfr(self.ssfr, chip.name)
        sets = self.sgset
        if isinstance(sets, (str, bytes, Mapping)) or not isinstance(sets, Iterable):
            raise ParameterError(
                f"sgset must be a sequence of at most {MAX_GAIN_SETS} gain sets ({chip.name}); "
                f"got sgset={sets!r}."
            )
        sets = list(sets)
        if len(sets) > MAX_GAIN_SETS:
            raise ParameterError(
                f"sgset holds at most {MAX_GAIN_SETS} stored gain sets (SGSET1 ... "
                f"SGSET{MAX_GAIN_SETS}) ({chip.name}); got {len(sets)}."
            )
        checked = tuple(_check_gain_set(s, i, chip.name) for i, s in enumerate(sets, start=1))
        object.__setattr__(self, "sgset", checked)
        object.__setattr__(self, "sgenb", _check_schedule(self.sgenb, len(checked), chip.name))

    # --- views -------------------------------------------------------------------------

    @property
    def gains(self) -> GainSet:
        """The gains in force at reset, as a :class:`GainSet`."""
        return GainSet(self.sgp, self.sgi, self.sgv, self.sgvf, self.sgaf)

    @property
    def sample_time_us(self) -> int:
        """Servo sampling period in microseconds (330, 185, 160 or 150), exact."""
        return SSFR_PERIOD_US[self.ssfr]

    @property
    def sample_time_s(self) -> float:
        """Servo sampling period in seconds (``sample_time_us / 1e6``)."""
        return self.sample_time_us / 1_000_000

    @property
    def trajectory_ticks(self) -> int:
        """Servo samples per motion trajectory update (equal to SSFR) [A: APEX615n table]."""
        return self.ssfr

    @property
    def motor_limit(self) -> int:
        """Largest positive motor command, 32752 (a 12-bit DAC's +full scale, PK-A2).

        The most negative command is -32768. With the 16-bit DAC of PK-A2's alternative the
        positive full scale is 32767; 32752 then still marks every saturated tick (the
        saturation metric counts ``|command| >= motor_limit``), and also the 15 codes below
        full scale.
        """
        return 32752

    def gains_at(self, tick: int) -> GainSet:
        """The gains in force at servo ``tick`` (counted from the filter's reset)."""
        active = 0
        for t, number in self.sgenb:
            if t <= tick:
                active = number
            else:
                break
        return self.gains if active == 0 else self.sgset[active - 1]

    # --- construction -------------------------------------------------------------------

    @classmethod
    def default(cls, model: str) -> Parker6kParams:
        """The default set of a model: the gains of the 6250 guide's worked tuning example
        (SGP85, SGV2.3; not the controller's power-up values), the rest as in the spec."""
        return cls(model=model)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Parker6kParams:
        """Build from a mapping of field names; unknown names raise with close matches.

        ``sgset`` may be a list of mappings of the five gains, ``sgenb`` a list of pairs.
        """
        if not isinstance(values, Mapping):
            raise ParameterError(
                f"values must be a mapping of parameter names; got {type(values).__name__}."
            )
        values = dict(values)
        model = values.pop("model", "6250")
        space = parameter_space(model)
        for name in values:
            if name not in FIELDS and name not in ("sgset", "sgenb"):
                close = difflib.get_close_matches(str(name), [*FIELDS, "sgset", "sgenb"], n=3)
                hint = f" Did you mean {', '.join(close)}?" if close else ""
                raise ParameterError(
                    f"{space.chip_model} has no parameter {name!r}; its parameters are "
                    f"{', '.join(FIELDS)}, sgset and sgenb.{hint}"
                )
        return cls(model=model, **values)

    def to_dict(self) -> dict[str, Any]:
        """Every field, ``model`` first; ``sgset`` as a list of dicts, ``sgenb`` of lists."""
        out: dict[str, Any] = {"model": self.model}
        out.update({n: getattr(self, n) for n in FIELDS})
        out["sgset"] = [s.to_dict() for s in self.sgset]
        out["sgenb"] = [[t, s] for t, s in self.sgenb]
        return out

    def enable(self, number: int) -> Parker6kParams:
        """What ``SGENB<number>`` does: a copy whose active gains are stored set ``number``.

        The stored sets and the schedule are kept. A scheduling env loads the copy between
        two runs of the loop (the filter state carries over, as on the controller).
        """
        n = len(self.sgset)
        if n == 0:
            raise ParameterError(
                f"enable needs a stored gain set, but sgset is empty ({self.model})."
            )
        number = _check_int(number, "set", 1, n, f"{self.model}; the stored sets are 1..{n}")
        return dataclasses.replace(self, **self.sgset[number - 1].to_dict())

    def to_array(self) -> np.ndarray:
        """Every register, stored set and switch as an int64 array for the kernel.

        Layout: period (us), ssfr, sgilim, soffs, smper; the active gains (set 0) and the
        five stored sets (unused sets zero), five gains each; the number of stored sets; the
        number of switches n; then the n switch ticks and the n set numbers.
        """
        n = len(self.sgenb)
        arr = np.zeros(P_SWITCHES + 2 * n, dtype=np.int64)
        arr[P_PERIOD_US] = self.sample_time_us
        arr[P_SSFR] = self.ssfr
        arr[P_SGILIM] = self.sgilim
        arr[P_SOFFS] = self.soffs
        arr[P_SMPER] = self.smper
        arr[P_GAINS : P_GAINS + 5] = self.gains.to_tuple()
        for i, s in enumerate(self.sgset, start=1):
            arr[P_GAINS + 5 * i : P_GAINS + 5 * i + 5] = s.to_tuple()
        arr[P_N_SETS] = len(self.sgset)
        arr[P_N_SWITCHES] = n
        for i, (tick, number) in enumerate(self.sgenb):
            arr[P_SWITCHES + i] = tick
            arr[P_SWITCHES + n + i] = number
        return arr


def format_decimal(value: int, places: int) -> str:
    """The controller's decimal form of a register count: ``8500, 2 -> '85'``,
    ``50, 2 -> '.5'``, ``-250, 3 -> '-.25'``, ``0 -> '0'``.

    Trailing zeros are dropped and, as in the manual's ``SGP.5,.5``, so is a leading zero.
    """
    if not isinstance(value, numbers.Integral) or isinstance(value, bool):
        raise ParameterError(f"a register value must be an integer; got {value!r}.")
    value = int(value)
    sign = "-" if value < 0 else ""
    whole, frac = divmod(abs(value), 10**places) if places else (abs(value), 0)
    text = str(whole) if whole else ""
    if frac:
        text += "." + f"{frac:0{places}d}".rstrip("0")
    return sign + text if text else "0"
