"""PMAC notch / low-pass design and frequency response (docs/chips/pmac.md, section 6)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servogym.chips import ParameterError
from servogym.chips.pmac import (
    PMACParams,
    PMACReferenceFilter,
    controller_response,
    design_low_pass,
    design_notch,
    notch_response,
    plot_frequency_response,
)

TS = PMACParams().sample_time_s  # 442.74 us


def manual(f_hz: float, zeta: float, ts: float) -> tuple[float, float]:
    """The manual's formulas, written out again: alpha, then the two coefficients."""
    w = 2 * math.pi * f_hz
    alpha = 1 + 2 * zeta * w * ts + w * w * ts * ts
    return -2 * (1 + zeta * w * ts) / alpha, 1 / alpha


def minimum_hz(design_or_params) -> float:
    ts = design_or_params.sample_time_s
    freqs = np.linspace(1.0, 0.5 / ts, 200_001)
    return float(freqs[np.argmin(notch_response(design_or_params, freqs).magnitude)])


def test_notch_coefficients_follow_the_manual():
    d = design_notch(120.0, TS, zero_damping=0.1, pole_hz=150.0, pole_damping=0.6)
    n1, n2 = manual(120.0, 0.1, TS)
    d1, d2 = manual(150.0, 0.6, TS)
    assert (d.notch_n1, d.notch_n2) == (round(n1 * 2**22), round(n2 * 2**22))
    assert (d.notch_d1, d.notch_d2) == (round(d1 * 2**22), round(d2 * 2**22))
    assert d.coefficients == pytest.approx((n1, n2, d1, d2), abs=2**-22)
    assert d.marks_hz == (120.0, 150.0)


def test_low_pass_matches_the_manuals_example_with_its_formula():
    # 60 Hz, zeta 0.707, 250 us: wn Ts = 0.0942, alpha = 1 + 0.1332 + 0.00887 = 1.1421,
    # Ixx38 = -2 (1.0666) / 1.1421 = -1.8678, Ixx39 = 0.8755, Ixx30 * 0.00777. (The manual's
    # printed example adds wn Ts instead of wn^2 Ts^2 to alpha: 1.146, -1.861, 0.873.)
    d = design_low_pass(60.0, 250e-6, damping=0.707, proportional_gain=100_000)
    assert d.notch_n1 == d.notch_n2 == 0
    assert d.coefficients[2] == pytest.approx(-1.8678, abs=1e-4)
    assert d.coefficients[3] == pytest.approx(0.8755, abs=1e-4)
    # DC gain of 1 / (1 + d1 + d2) = alpha / (wn Ts)^2 = 128.6; 100000 / 128.6 = 777.7.
    assert float(d.dc_gain) == pytest.approx(1.1421 / 0.0942478**2, rel=1e-3)
    assert d.proportional_gain == 778
    assert d.registers() == {
        "notch_n1": 0,
        "notch_n2": 0,
        "notch_d1": d.notch_d1,
        "notch_d2": d.notch_d2,
        "proportional_gain": 778,
    }


@pytest.mark.parametrize(("zero_hz", "tolerance"), [(30.0, 0.005), (60.0, 0.01), (100.0, 0.02)])
def test_notch_minimum_where_requested(zero_hz, tolerance):
    # The manual's procedure: the backward difference puts the minimum a little low.
    d = design_notch(zero_hz, TS)
    assert minimum_hz(d) == pytest.approx(zero_hz, rel=tolerance)
    assert minimum_hz(d) < zero_hz


@pytest.mark.parametrize("zero_hz", [60.0, 150.0, 300.0, 450.0])
@pytest.mark.parametrize("pole_ratio", [1.0, 1.4])
def test_prewarped_notch_minimum_on_the_requested_frequency(zero_hz, pole_ratio):
    d = design_notch(zero_hz, TS, pole_hz=pole_ratio * zero_hz, prewarp=True)
    assert minimum_hz(d) == pytest.approx(zero_hz, rel=1e-3)
    assert d.marks_hz == (zero_hz, pole_ratio * zero_hz)


def test_notch_in_the_parameter_set_and_the_dc_gain_kept():
    base = PMACParams(proportional_gain=40_000, derivative_gain=0, velocity_ff=0)
    d = design_notch(90.0, TS, pole_hz=150.0, pole_damping=0.5, proportional_gain=40_000)
    p = d.apply(base)
    assert p.proportional_gain == d.proportional_gain == round(40_000 / float(d.dc_gain))
    assert p.notch_n1 == d.notch_n1 and p.notch_d2 == d.notch_d2
    # The loop's gain at DC is unchanged (to the rounding of Ixx30).
    lo = [0.01]
    old, new = controller_response(base, lo).magnitude[0], controller_response(p, lo).magnitude[0]
    assert new == pytest.approx(old, rel=1 / 40_000)
    assert old == pytest.approx(2**-19 * 40_000 * 96, rel=1e-6)
    # And so is the filter's settled output for a held error (the bit-exact filter).
    n = 3000
    steady = [PMACReferenceFilter(q).run([50] * n, [0] * n, [0] * n)[-1] for q in (base, p)]
    assert abs(steady[0] - steady[1]) <= 1
    # The minimum of the whole filter's response is at the notch too.
    freqs = np.linspace(20.0, 400.0, 20_001)
    c = controller_response(p, freqs)
    assert freqs[np.argmin(c.magnitude)] == pytest.approx(minimum_hz(d), rel=2e-3)


def test_response_of_an_empty_notch_is_one():
    r = notch_response(PMACParams(), [0.0, 10.0, 500.0, 1000.0])
    np.testing.assert_allclose(r.magnitude, 1.0)
    np.testing.assert_allclose(r.phase_deg, 0.0, atol=1e-12)
    assert r.unit == "1" and r.magnitude_db.tolist() == [0.0] * 4


def test_plot_writes_a_png(tmp_path):
    p = design_notch(200.0, TS, prewarp=True).apply(PMACParams(proportional_gain=30_000))
    out = plot_frequency_response(p, tmp_path / "response.png", mark_hz=[200.0], title="notch")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    only = plot_frequency_response(design_low_pass(100.0, TS), tmp_path / "lp.png")
    assert only.stat().st_size > 5_000


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: design_notch(0.0, TS), "zero_hz must be a finite number > 0"),
        (lambda: design_notch(1200.0, TS), r"0 < zero_hz < 1129.33 Hz"),
        (lambda: design_notch(100.0, TS, zero_damping=1.0), "0 <= zero_damping < 1"),
        (lambda: design_notch(100.0, TS, pole_damping=True), "0 <= pole_damping < 1"),
        (lambda: design_notch(100.0, -1.0), "sample_time_s must be a finite number > 0"),
        (lambda: design_low_pass(100.0, TS, damping=-0.1), "0 <= damping < 1"),
        (
            lambda: design_notch(20.0, TS, pole_hz=1000.0, proportional_gain=8_000_000),
            r"-8388608 <= proportional_gain <= 8388607",
        ),
        (
            lambda: design_notch(100.0, TS).apply(PMACParams(servo_cycle_extension=1)),
            "designed for sample_time_s",
        ),
        (lambda: notch_response("I136=0"), "PMACParams or a FilterDesign"),
        (lambda: notch_response(PMACParams(), [[1.0]]), "freqs_hz must be a non-empty 1-D"),
    ],
)
def test_illegal_design_arguments(call, match):
    with pytest.raises(ParameterError, match=match):
        call()


def test_notch_depth_of_the_backward_difference():
    # The zeros land inside the unit circle: the notch has a finite depth (spec section 6).
    depth = [notch_response(design_notch(f, TS), [f * 0.983]).magnitude[0] for f in (100.0,)]
    assert 0.25 < depth[0] < 0.35
    freqs = np.linspace(1.0, 0.5 / TS, 50_001)
    assert notch_response(design_notch(200.0, TS), freqs).magnitude.min() == pytest.approx(
        0.50, abs=0.01
    )
