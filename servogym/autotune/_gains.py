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


GAIN_MAPS: dict[str, GainMap] = {}
"""The gain map of each chip family that has one, by family name."""


def register_gain_map(gain_map: GainMap) -> GainMap:
    """Let the classical tuners work on a chip family (see docs/autotune.md)."""
    GAIN_MAPS[gain_map.family] = gain_map
    return gain_map


register_gain_map(PMDGainMap())


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
