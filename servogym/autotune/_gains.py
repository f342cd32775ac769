"""Controller designs in physical units and their mapping onto each chip family's registers.

The classical tuners design a PID with feed-forward in units every chip shares: the motor
command in counts of the 16-bit output (32768 = full scale) and the error in encoder counts.
A small per-family :class:`GainMap` turns such a :class:`ServoDesign` into legal registers.
A family without a map cannot use the classical tuners until one is registered with
:func:`register_gain_map` (the Optuna tuners need none).
"""

from __future__ import annotations

import abc
import dataclasses
import math
from collections.abc import Mapping
from typing import Any

from servogym.chips._family import ChipFamily, get_chip
from servogym.chips._space import ParameterSpace


@dataclasses.dataclass(frozen=True)
class ServoDesign:
    """A PID position loop with feed-forward, independent of any chip.

    The motor command is ``bias + p*e + i*integral(e) + d*de/dt + vff*v_cmd + aff*a_cmd``,
    the integral term limited to ``integral_limit``, the sum to ``motor_limit``.

    Attributes:
        p: Proportional gain (command counts per count of error).
        i: Integral gain (command counts per count*s).
        d: Derivative gain (command counts per count/s).
        integral_limit: Largest magnitude of the integral term (command counts).
        vff: Velocity feed-forward (command counts per count/s of commanded velocity).
        aff: Acceleration feed-forward (command counts per count/s^2).
        bias: Constant command (command counts), e.g. the gravity holding command.
        derivative_sample_s: Interval of the derivative's difference (s); ``None``: every
            servo cycle. A longer interval filters encoder quantization.
        motor_limit: Command limit (command counts); ``None`` keeps the chip's default.
    """

    p: float = 0.0
    i: float = 0.0
    d: float = 0.0
    integral_limit: float = 0.0
    vff: float = 0.0
    aff: float = 0.0
    bias: float = 0.0
    derivative_sample_s: float | None = None
    motor_limit: float | None = None

    def replace(self, **changes: Any) -> ServoDesign:
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)


class GainMap(abc.ABC):
    """Turns a :class:`ServoDesign` into one chip family's registers.

    Attributes:
        family: The family's registry name.
    """

    family: str

    @abc.abstractmethod
    def registers(self, design: ServoDesign, base: Any, assumptions: Any = None) -> dict[str, int]:
        """Register values realising ``design`` on the chip of ``base``, each legal.

        Args:
            design: The controller.
            base: The parameter set the design is applied to (chip model, servo period).
            assumptions: The family's assumption switches (``None``: defaults).

        Registers the design does not concern keep the model's defaults. Values beyond a
        register's range are clamped to it (a design may ask for more than a chip can do).
        """


def _clamp(space: ParameterSpace, name: str, value: float) -> int:
    spec = space[name]
    if not math.isfinite(value):
        value = spec.high if value > 0 else spec.low
    return int(min(spec.high, max(spec.low, round(value))))


class PMDGainMap(GainMap):
    """PMD Navigator / Pilot / Magellan (docs/chips/pmd.md).

    The filter sums ``kp*E + kd*D + (ki*I >> s) + kvff*V + kaff*A`` and scales the sum by
    ``kout/65536`` (PMD-A4: the feed-forward terms too unless switched). Here ``E`` is in
    counts, ``D`` the error difference over ``derivative_time`` cycles, ``I`` the error sum
    per cycle bounded by ``integration_limit``, ``s`` 8 (PMD-A2), ``V`` and ``A`` the commanded
    velocity and acceleration in counts/cycle and counts/cycle^2. ``kout`` is chosen as the
    smallest value that lets the largest gain fit its 15 bits, for the finest resolution.
    """

    family = "pmd"

    def registers(self, design: ServoDesign, base: Any, assumptions: Any = None) -> dict[str, int]:
        from servogym.chips.pmd import PMDAssumptions

        a = assumptions if assumptions is not None else PMDAssumptions()
        space = base.space
        dt = base.sample_time_s
        shift = 8 if a.integral_shift == "8" else 0
        dtime = 1
        if design.derivative_sample_s is not None:
            dtime = _clamp(space, "derivative_time", design.derivative_sample_s / dt)
        # Register values the gains need at kout = 65536 (unity output scale).
        raw = {
            "kp": design.p,
            "kd": design.d / (dtime * dt),
            "ki": design.i * dt * 2**shift,
        }
        ff = {"kvff": design.vff / dt, "kaff": design.aff / dt**2}
        ff_scaled = a.kout_scales_feedforward == "yes"
        if ff_scaled:
            raw.update(ff)
        gain_max = space["kp"].high
        biggest = max(max(raw.values()), 0.0)
        kout_max = space["kout"].high
        kout = kout_max if biggest == 0 else math.ceil(biggest * 65536 / gain_max)
        kout = int(min(kout_max, max(1, kout)))
        out = {name: _clamp(space, name, v * 65536 / kout) for name, v in raw.items()}
        if not ff_scaled:
            out.update({name: _clamp(space, name, v) for name, v in ff.items()})
        out["kout"] = kout
        out["derivative_time"] = dtime
        if out["ki"] > 0 and design.integral_limit > 0:
            # integral term = (ki * I >> s) * kout / 65536 <= integral_limit
            limit = design.integral_limit * 65536 * 2**shift / (out["ki"] * kout)
            out["integration_limit"] = _clamp(space, "integration_limit", limit)
        else:
            out["integration_limit"] = 0
        out["bias"] = _clamp(space, "bias", design.bias)
        if design.motor_limit is not None:
            out["motor_limit"] = _clamp(space, "motor_limit", design.motor_limit)
        return out


def _clamp_nonneg(space: ParameterSpace, name: str, value: float) -> int:
    """Like :func:`_clamp`, but never below 0 (a negative gain would invert a term)."""
    return max(0, _clamp(space, name, value))


class PMACGainMap(GainMap):
    """Delta Tau Turbo PMAC / Geo Brick (docs/chips/pmac.md, section 3).

    The manual's equation, in DAC bits (the 16-bit command) with ``T`` the filter period:

        DAC = 2^-19 Ixx30 {Ixx08 [FE + (Ixx32 CV + Ixx35 CA)/128 + Ixx33 IE/2^23]
                           - Ixx31 Ixx09 AV/128}

    with FE in counts, CV, AV in counts per update, CA in counts per update^2, IE the error
    sum per update. Ixx30 is the overall gain, so it is set first, from ``p``, and every
    other register is computed with the rounded Ixx30:

    ========  ==================================================================
    Ixx30     ``p * 2^19 / Ixx08``
    Ixx31     ``d * 2^26 / (Ixx30 * Ixx09 * T)``
    Ixx32     ``(vff + d') * 2^26 / (Ixx30 * Ixx08 * T)``, ``d'`` the d Ixx31 realises
    Ixx35     ``aff * 2^26 / (Ixx30 * Ixx08 * T^2)``
    Ixx33     ``i * T * 2^42 / (Ixx30 * Ixx08)``
    Ixx63     ``integral_limit * 2^23 / (Ixx08 * Ixx30)`` (0 without an integral)
    Ixx34     0 (integrate always, as the design does)
    Ixx29     ``bias``; Ixx69 ``motor_limit`` (when given)
    ========  ==================================================================

    PMAC's derivative acts on the *actual* velocity only (``-Ixx31 AV``), the design's on
    the error's rate ``CV - AV``; the ``d * CV`` part is realised through Ixx32, hence the
    ``vff + d`` (with Ixx08 = Ixx09 and no feed-forward, Ixx32 = Ixx31: the controller's
    own defaults follow that rule). Not realisable: ``derivative_sample_s`` (PMAC has no
    derivative interval; Ixx60 would slow the whole filter), and a design with ``p = 0``
    but other terms (Ixx30 = 0 switches every term off; Ixx30 = 1 is used instead).
    Ixx08 and Ixx09 keep the base set's values. The notch and the friction feed-forward
    Ixx68 are not part of a design and keep the base values.
    """

    family = "pmac"

    def registers(self, design: ServoDesign, base: Any, assumptions: Any = None) -> dict[str, int]:
        space = base.space
        dt = base.sample_time_s
        ix08 = int(base.position_loop_scale)
        ix09 = int(base.velocity_loop_scale)
        out: dict[str, int] = {}
        kp = _clamp_nonneg(space, "proportional_gain", design.p * 2**19 / max(ix08, 1))
        others = (design.i, design.d, design.vff, design.aff)
        if kp == 0 and any(v > 0 for v in others):
            kp = 1
        out["proportional_gain"] = kp
        if kp == 0 or ix08 == 0:
            # Nothing can be realised through a zero overall gain.
            out.update(derivative_gain=0, velocity_ff=0, acceleration_ff=0, integral_gain=0,
                       integration_limit=0)  # fmt: skip
        else:
            step_d = kp * max(ix09, 1) * dt / 2**26  # command per count/s of actual velocity
            out["derivative_gain"] = _clamp_nonneg(space, "derivative_gain", design.d / step_d)
            unit_v = kp * ix08 * dt / 2**26  # command per count/s of commanded velocity
            # The d*CV part uses the realised Ixx31, so at a steady velocity (CV = AV) the
            # two roundings do not add up.
            d_realised = out["derivative_gain"] * step_d
            out["velocity_ff"] = _clamp_nonneg(
                space, "velocity_ff", (design.vff + d_realised) / unit_v
            )
            out["acceleration_ff"] = _clamp_nonneg(
                space, "acceleration_ff", design.aff / (unit_v * dt)
            )
            out["integral_gain"] = _clamp_nonneg(
                space, "integral_gain", design.i * dt * 2**42 / (kp * ix08)
            )
            if out["integral_gain"] > 0 and design.integral_limit > 0:
                limit = design.integral_limit * 2**23 / (ix08 * kp)
                out["integration_limit"] = _clamp_nonneg(space, "integration_limit", limit)
            else:
                out["integration_limit"] = 0
        out["integration_mode"] = 0
        out["output_bias"] = _clamp(space, "output_bias", design.bias)
        if design.motor_limit is not None:
            out["output_limit"] = _clamp(space, "output_limit", design.motor_limit)
        return out

    def design(self, values: Mapping[str, int], base: Any) -> ServoDesign:
        """The design a register set realises (inverse of :meth:`registers`).

        Args:
            values: Registers by name (every one :meth:`registers` sets).
            base: A parameter set giving Ixx08, Ixx09 and the filter period.
        """
        dt = base.sample_time_s
        ix08, ix09 = int(base.position_loop_scale), int(base.velocity_loop_scale)
        kp = values["proportional_gain"]
        unit_v = kp * ix08 * dt / 2**26
        d = values["derivative_gain"] * kp * ix09 * dt / 2**26
        i = values["integral_gain"] * kp * ix08 / (dt * 2**42)
        return ServoDesign(
            p=kp * ix08 / 2**19,
            i=i,
            d=d,
            integral_limit=values["integration_limit"] * ix08 * kp / 2**23 if i > 0 else 0.0,
            vff=values["velocity_ff"] * unit_v - d,
            aff=values["acceleration_ff"] * unit_v * dt,
            bias=float(values["output_bias"]),
            motor_limit=float(values["output_limit"]) if "output_limit" in values else None,
        )


class Parker6kGainMap(GainMap):
    """Parker Compumotor 6250 / 6K PIV&F (docs/chips/parker6k.md, section 4).

    Every term is in signal units ``q`` (0.01 of PK-A1's voltage unit) and the motor command
    is ``32768 * Y / FS`` (``FS`` q in 10 V), so one command count is ``c = FS / 32768`` q.
    Gains are stored in steps of 0.01 (SGAF 0.0001) of their unit, i.e. one register step
    times one input unit is one q (SGAF: 1/100 q):

    =======  ============================================================================
    SGP      ``p * c`` (per count)
    SGV      ``d * c`` (per count/s of encoder velocity)
    SGVF     ``vff * c + SGV`` under PK-A3 ``encoder``; ``vff * c`` under ``error_rate``
    SGAF     ``aff * c * 100`` (per count/s^2)
    SGI      ``i * c`` (per count*s)
    SGILIM   ``integral_limit * 10000 / 32768`` mV (the bound on the integral term)
    SOFFS    ``bias * 10000 / 32768`` mV
    =======  ============================================================================

    Under PK-A3 ``encoder`` SGV damps the encoder velocity only, so the design's
    ``d * de/dt`` needs ``d`` on the commanded velocity as well: SGVF carries it. Not
    realisable: ``motor_limit`` (the controller has no output-limit setting; the +/-10 V
    DAC is the limit, so the relay tuner's relay always swings full scale), and
    ``derivative_sample_s``. Under PK-A1 ``mV`` the steps are 1000x coarser (SGAF of a fine
    encoder rounds to a few steps or to 0). Only the gains in force at reset are set; the
    stored gain sets (SGSET) and the SGENB schedule keep the base values.
    """

    family = "parker6k"

    @staticmethod
    def _units(assumptions: Any) -> tuple[float, bool]:
        from servogym.chips.parker6k import Parker6kAssumptions

        a = assumptions if assumptions is not None else Parker6kAssumptions()
        full_scale_q = 1e9 if a.gain_unit == "uV" else 1e6
        return full_scale_q / 32768.0, a.velocity_feedback == "encoder"

    def registers(self, design: ServoDesign, base: Any, assumptions: Any = None) -> dict[str, int]:
        space = base.space
        c, encoder = self._units(assumptions)
        mv = 10000.0 / 32768.0  # mV per command count
        sgv = _clamp_nonneg(space, "sgv", design.d * c)
        out = {
            "sgp": _clamp_nonneg(space, "sgp", design.p * c),
            "sgv": sgv,
            # The d*Vc part uses the realised SGV (the roundings cancel at steady velocity).
            "sgvf": _clamp_nonneg(space, "sgvf", design.vff * c + (sgv if encoder else 0)),
            "sgaf": _clamp_nonneg(space, "sgaf", design.aff * c * 100),
            "sgi": _clamp_nonneg(space, "sgi", design.i * c),
        }
        if out["sgi"] > 0 and design.integral_limit > 0:
            out["sgilim"] = _clamp_nonneg(space, "sgilim", design.integral_limit * mv)
        else:
            out["sgilim"] = 0
        out["soffs"] = _clamp(space, "soffs", design.bias * mv)
        return out

    def design(self, values: Mapping[str, int], base: Any, assumptions: Any = None) -> ServoDesign:
        """The design a register set realises (inverse of :meth:`registers`).

        Args:
            values: Registers by name (every one :meth:`registers` sets).
            base: A parameter set of the family (unused: the map needs no period).
            assumptions: The family's assumption switches (``None``: defaults).
        """
        c, encoder = self._units(assumptions)
        mv = 10000.0 / 32768.0
        d = values["sgv"] / c
        i = values["sgi"] / c
        return ServoDesign(
            p=values["sgp"] / c,
            i=i,
            d=d,
            integral_limit=values["sgilim"] / mv if i > 0 else 0.0,
            vff=values["sgvf"] / c - (d if encoder else 0.0),
            aff=values["sgaf"] / (c * 100),
            bias=values["soffs"] / mv,
        )


GAIN_MAPS: dict[str, GainMap] = {}
"""The gain map of each chip family that has one, by family name."""


def register_gain_map(gain_map: GainMap) -> GainMap:
    """Let the classical tuners work on a chip family (see docs/autotune.md)."""
    GAIN_MAPS[gain_map.family] = gain_map
    return gain_map


register_gain_map(PMDGainMap())
register_gain_map(PMACGainMap())
register_gain_map(Parker6kGainMap())


def gain_map_for(family: ChipFamily | str) -> GainMap:
    """The gain map of a chip family, or an error saying how to add one."""
    name = family if isinstance(family, str) else family.name
    try:
        return GAIN_MAPS[name]
    except KeyError:
        from servogym.autotune._session import TuneError

        raise TuneError(
            f"the classical tuners (vendor-step, relay, model-based) need a gain map for chip "
            f"family {name!r}, and none is registered; families with one: "
            f"{', '.join(GAIN_MAPS)}. Write a servogym.autotune.GainMap subclass that turns a "
            "ServoDesign into that family's registers and register it with "
            "servogym.autotune.register_gain_map (docs/autotune.md), or use an Optuna tuner "
            "(tpe, gp, cmaes, random, sobol)."
        ) from None


def design_registers(
    design: ServoDesign, base: Any, base_values: Mapping[str, int], assumptions: Any = None
) -> dict[str, int]:
    """``base_values`` updated with the registers the family's map gives ``design``."""
    family, _ = get_chip(base.model)
    return {**base_values, **gain_map_for(family).registers(design, base, assumptions)}
