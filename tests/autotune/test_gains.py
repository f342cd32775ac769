"""Physical designs onto chip registers, and the rules of the classical tuners."""

from __future__ import annotations

import cmath
import math

import numpy as np
import pytest

from servogym.autotune import (
    GAIN_MAPS,
    ServoDesign,
    TuneError,
    astrom_hagglund,
    design_registers,
    gain_map_for,
    identify_rigid_axis,
)
from servogym.autotune._classical import MAX_PID_LEAD_DEG
from servogym.chips._family import families
from servogym.chips.pmd import PMDAssumptions, PMDParams


@pytest.mark.parametrize("model", ["MC2100", "MC58000"])
def test_the_pmd_map_realises_the_designed_gains(model):
    base = PMDParams.default(model)
    dt = base.sample_time_s
    design = ServoDesign(p=1.3, i=900.0, d=0.004, integral_limit=3000.0, vff=0.02,
                         aff=2e-5, bias=-740.0, derivative_sample_s=3 * dt)  # fmt: skip
    regs = design_registers(design, base, base.to_dict())
    params = PMDParams.from_dict(regs)  # legal
    k = 65536 / params.kout  # each register is the nearest integer to gain * 65536 / kout
    assert params.derivative_time == 3
    assert params.kp == round(design.p * k)
    assert params.kd == round(design.d / (3 * dt) * k)
    assert params.ki == round(design.i * dt * 256 * k)
    assert params.kvff == round(design.vff / dt * k)
    assert params.kaff == round(design.aff / dt**2 * k)
    scale = 1 / k
    assert params.ki * params.integration_limit / 256 * scale == pytest.approx(3000, rel=1e-3)
    assert params.bias == -740
    # The largest gain uses the 15 bits, for the finest resolution.
    assert max(params.kp, params.kd, params.ki, params.kvff, params.kaff) > 16384


def test_the_pmd_map_follows_the_assumption_switches():
    base = PMDParams.default("MC2100")
    design = ServoDesign(p=1.0, i=500.0, vff=0.01)
    a = design_registers(design, base, base.to_dict())
    b = design_registers(
        design,
        base,
        base.to_dict(),
        PMDAssumptions(integral_shift="0", kout_scales_feedforward="no"),
    )
    dt = base.sample_time_s
    assert a["ki"] == round(500.0 * dt * 256 * 65536 / a["kout"])
    assert a["kvff"] == round(0.01 / dt * 65536 / a["kout"])
    assert b["ki"] == round(500.0 * dt * 65536 / b["kout"])  # no >> 8 (PMD-A2 = 0)
    assert b["kvff"] == round(0.01 / dt)  # added after the Kout scaling (PMD-A4 = no)


def test_a_design_beyond_the_registers_is_clamped_to_legal_values():
    base = PMDParams.default("MC2100")
    regs = design_registers(ServoDesign(p=1e9, bias=1e6, motor_limit=-5), base, base.to_dict())
    PMDParams.from_dict(regs)
    assert regs["bias"] == 32767 and regs["motor_limit"] == 0


def test_a_family_without_a_gain_map_gets_the_extension_point_in_the_error():
    # Every built-in family has a map now; a new family (a made-up name) gets the pointer.
    assert set(families()) <= set(GAIN_MAPS)
    with pytest.raises(TuneError, match=r"register_gain_map.*docs/autotune.md"):
        gain_map_for("a-new-family")


def test_the_astrom_hagglund_rule_puts_the_loop_on_the_unit_circle_with_the_margin():
    g, delay, w = 1e4, 2e-4, 600.0

    def plant(s):
        return g / s**2 * cmath.exp(-s * delay)

    gjw = plant(1j * w)
    p, i, d = astrom_hagglund(w, abs(gjw), math.degrees(cmath.phase(gjw)), 45.0)
    loop = (p + i / (1j * w) + d * 1j * w) * gjw
    assert abs(loop) == pytest.approx(1.0, rel=1e-9)
    assert math.degrees(cmath.phase(loop)) == pytest.approx(-180 + 45, abs=1e-6)
    assert d / p == pytest.approx(4 * p / i / 16, rel=1e-9)  # Ti = 4 Td


def test_the_astrom_hagglund_rule_keeps_positive_gains_when_the_point_lags_too_much():
    # A relay point lagged by the loop latency (issue 13: 6250's relay oscillation measured
    # phase +112.8 deg = -247.2 deg, gain 4.26e-4 at 781 Hz). Clipping phi_b at -60 deg asked
    # the PID for 105 deg of lead; cos(105 deg) < 0 made every gain negative (and the
    # registers 0). The lead is now capped at MAX_PID_LEAD_DEG.
    w, gain, phase = 2 * math.pi * 781.25, 4.26e-4, 112.8
    p, i, d = astrom_hagglund(w, gain, phase, 45.0)
    assert p > 0 and i > 0 and d > 0
    gjw = gain * cmath.exp(1j * math.radians(phase))
    lead = math.degrees(cmath.phase(p + i / (1j * w) + d * 1j * w))
    assert lead == pytest.approx(MAX_PID_LEAD_DEG, abs=1e-6)
    assert abs((p + i / (1j * w) + d * 1j * w) * gjw) == pytest.approx(1.0, rel=1e-9)


def test_identification_recovers_a_known_rigid_axis():
    g, coulomb, viscous, gravity, dt = 3e4, 250.0, 0.002, 770.0, 1e-4
    rng = np.random.default_rng(0)
    n = 6000
    u = np.repeat(rng.choice([-3000.0, -1500.0, 1500.0, 3000.0], n // 200), 200)
    x = np.zeros(n)
    v = 0.0
    for k in range(n - 1):
        a = g * (u[k] - coulomb * np.sign(v) - viscous * v - gravity)
        v += a * dt
        x[k + 1] = x[k] + v * dt
    fit = identify_rigid_axis(u, np.floor(x), dt)
    assert fit["accel_gain"] == pytest.approx(g, rel=0.03)
    assert fit["gravity_cmd"] == pytest.approx(gravity, rel=0.05)
    assert fit["coulomb_cmd"] == pytest.approx(coulomb, rel=0.1)
