"""``ChipFamily.filter_response`` against the integer reference filters it linearises.

Method. The plain-Python reference of every chip model (from the registry) is driven with a
sinusoidal position error ``E(n) = round(A cos(2 pi f (n + 1/2)))`` at ``f`` = 1/91, 3/91
and 12/91 of the sample rate (0.011, 0.033, 0.132), on the feedback path (commanded
position held at 0, actual position ``-E``) and on the commanded path (``CP = E``, actual
0). After ``SKIP`` samples (fade-in and transient), the complex amplitudes at ``f`` of the
output and of the input are taken over whole periods and their ratio is the measured
response.

Why this is exact up to rounding. The rounded input repeats every ``PERIOD`` = 91 samples
and sums to 0 over a period (:func:`stimulus`), so the integrators see no drift. The
measured span is a whole number of periods of the input and of the derivative sampling
(PMD DerivativeTime ``d`` = 1, 3, 4, 10; :func:`window`), so the DFT bin at ``f``
separates exactly every other frequency the filter puts out: the harmonics ``k f`` of the
input's rounding and, for ``d`` > 1 (a periodically time-varying filter), their aliases
``+-k f + m/d``. Since 91 is coprime to every ``d``, no alias of any harmonic falls on
``f`` (``(k -+ 1) p / 91 = m / d`` mod 1 only for ``k = +-1, m = 0``), so the bin holds the
filter's response at ``f`` times the input's own bin, which the ratio divides out. What is
left is the output's rounding: an error ``e(n)`` within ``[0, q)`` (floor) or ``(-q, q)``
(toward zero) moves a bin by at most ``2 q``, with ``q`` one count (PMD, PMAC) or the DAC
step (Parker: 16 counts at 12 bits). The amplitude is chosen so the output's is at least
``4 q / TOL`` (and ``TARGET`` where the filter's internal limits allow), so rounding
accounts for at most half of ``TOL``: a relative complex error of ``TOL`` = 0.5 %, i.e.
0.5 % in gain and 0.29 degree in phase. The largest error measured is 0.075 % (Parker,
12-bit DAC steps); PMD and PMAC stay below 0.01 %.

Gains are chosen so nothing saturates: every limit is opened (integration limits, error
trips, motor/output limits) and the amplitude is capped below each internal word's range
(PMD's 16-bit derivative, PMAC's 24-bit velocity words and integrator limit).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from servogym.chips import all_models, families, get_chip
from servogym.chips.pmac import design_notch
from servogym.chips.pmac._response import notch_transfer

MODELS = sorted(all_models())
PERIOD = 91
"""Samples per period of the test input; coprime to every DerivativeTime used (1, 3, 4, 10)."""
FREQS = (1 / PERIOD, 3 / PERIOD, 12 / PERIOD)
"""Test frequencies, cycles per sample: 0.011, 0.033, 0.132."""
SKIP = 800
"""Samples discarded: the fade-in and the transient (the slowest pole of the test sets,
|p| = 0.8, decays to 1e-38 in the 400 samples after the fade-in)."""
FADE = 400
"""Samples over which the input fades in."""
WINDOW = 500
"""At least this many samples are measured: whole periods of the input and of the
derivative sampling (:func:`window`)."""
TARGET = 16000
"""Output amplitude aimed at (command counts), where the internal limits allow it."""
PEAK = 30000
"""Largest output allowed (command counts): below every output limit of the test sets."""
TOL = 0.005
"""Relative complex error allowed: 0.5 % in gain, 0.29 degree in phase."""

LINEAR_SWITCHES = {
    "pmd": ("integral_shift", "derivative_mode", "biquad_format"),
    "pmac": ("integral_timing",),
    "parker6k": ("gain_unit", "integral_timing"),
}
"""The assumption switches that change the linear part; every other one must not."""


# --- the parameter sets -------------------------------------------------------------------


def pmd_values(model: str, derivative_time: int = 3) -> dict:
    values = dict(
        kp=300,
        ki=400,
        kd=600,
        kout=4000,
        integration_limit=2**31 - 1,
        derivative_time=derivative_time,
        position_error_limit=2**31 - 1,
        motor_limit=32767,
    )
    if model == "MC58000":
        # Stage 1: a notch-like section (zeros at 0.2 fs), stage 2: a low-pass (poles at
        # 0.7 e^{+-j 0.2 pi} in Q14). Read as Q15 (PMD-A12) every coefficient halves; both
        # readings are stable.
        values.update(
            biquad1_enable=1,
            biquad1_b0=8192,
            biquad1_b1=-5063,
            biquad1_b2=8192,
            biquad1_a1=-8094,
            biquad1_a2=10486,
            biquad1_k=24000,
            biquad2_enable=1,
            biquad2_b0=1462,
            biquad2_b1=2925,
            biquad2_b2=1462,
            biquad2_a1=-18563,
            biquad2_a2=8028,
            biquad2_k=16384,
        )
    return values


def linear_params(family, model: str, asm):
    """A set whose every term is exercised and nothing saturates at the test amplitudes."""
    if family.name == "pmd":
        return family.make_params(model, pmd_values(model))
    if family.name == "pmac":
        params = family.make_params(
            model,
            dict(
                proportional_gain=20000,
                derivative_gain=2000,
                integral_gain=420000,
                integration_limit=8388607,
                big_step_limit=8388607,
                output_limit=32767,
                fatal_following_error_limit=0,
            ),
        )
        # A notch at 0.08 of the sample rate (Ixx30 rescaled to keep the DC gain).
        return design_notch(0.08 / params.sample_time_s, params.sample_time_s).apply(params)
    # Parker: SGP300, SGI90000, SGV.5 in uV; in mV (PK-A1) SGP.3, SGI90, SGV.01, so the
    # output stays in range (SGV's smallest step is 20 times the scaled .0005).
    gains = dict(sgp=30000, sgi=9000000, sgv=50)
    if asm.gain_unit == "mV":
        gains = dict(sgp=30, sgi=9000, sgv=1)
    return family.make_params(model, dict(gains, smper=2**31 - 1))


def output_step(family, asm) -> int:
    """The command's rounding step q (counts): the DAC step for Parker, else 1."""
    if family.name == "parker6k":
        return 2 ** (16 - int(asm.dac_bits))
    return 1


def amplitude_cap(family, params, asm, f: float) -> float:
    """Largest input amplitude (counts) that keeps every internal word off its limit."""
    rate = 2 * math.sin(math.pi * f)  # |E(n) - E(n-1)| per count of amplitude
    if family.name == "pmd":
        return 10000.0  # the 16-bit derivative sees at most 2 A
    if family.name == "parker6k":
        return 20000.0
    word = 0.8 * 2**23 / (32 * max(params.velocity_loop_scale, params.position_loop_scale))
    cap = min(20000.0, word / rate)  # 24-bit velocity words (PMAC-A10)
    if params.integral_gain:
        # The integrator sum Ixx33 * 32 * sum(E) (peak A / rate) within Ixx63 * 2^24.
        cap = min(cap, 0.8 * params.integration_limit * 2**24 * rate / (params.integral_gain * 32))
    if asm.notch_form == "df2":
        # Direct form II's inner word v = x / (1 + d1 z^-1 + d2 z^-2) within its width.
        zi = np.exp(-2j * np.pi * f)
        poles = abs(1 + (params.notch_d1 * zi + params.notch_d2 * zi**2) / 2**22)
        notch = abs(notch_transfer(params, zi))
        dac = abs(complex(family.filter_response(params, asm, 1 / zi))) / notch
        # x per count: the DAC value's word O (x 256) after Ixx30, or Y (x 2^24 / Ixx30).
        x, bits = (256 * dac, 24) if asm.notch_position == "after_kp" else (
            2**24 * dac / params.proportional_gain, 32)  # fmt: skip
        cap = min(cap, 0.8 * 2 ** (bits - 1) * poles / x)
    return cap


# --- the measurement ----------------------------------------------------------------------


def stimulus(amplitude: float, f: float, n: int) -> np.ndarray:
    """``round(A cos(2 pi f (k + 1/2)))``: one period repeated, faded in over ``FADE``.

    The half-sample phase puts the running sum's mean at 0, so an integrator swings about
    zero (a sine from k = 0 would add about A / (2 pi f) to it); within a period the
    rounding is adjusted by one count where it was closest to a tie so the period sums to
    exactly 0, so an integrator never drifts. The raised-cosine fade-in spares the filter
    a step (a derivative kick that would clip the output and wind the integrator up).
    """
    k = np.arange(PERIOD)
    x = amplitude * np.cos(2 * np.pi * f * (k + 0.5))
    e = np.round(x)
    excess = int(e.sum())
    order = np.argsort(x - e)  # most rounded up first
    if excess > 0:
        e[order[:excess]] -= 1
    elif excess < 0:
        e[order[excess:]] += 1
    assert e.sum() == 0 and np.max(np.abs(e - x)) < 1
    out = np.resize(e, n)
    ramp = np.arange(FADE)
    out[:FADE] = np.round(x[ramp % PERIOD] * (1 - np.cos(np.pi * ramp / FADE)) / 2)
    return out.astype(np.int64)


def window(params) -> int:
    """Whole periods of the input and of PMD's derivative sampling, at least ``WINDOW``."""
    period = math.lcm(PERIOD, getattr(params, "derivative_time", 1))
    return period * math.ceil(WINDOW / period)


def measure(family, params, asm, f: float, path: str, amplitude: float) -> tuple[complex, int]:
    """Output over input at ``f`` from the reference filter (module doc), and the peak output."""
    n = np.arange(SKIP + window(params))
    e = stimulus(amplitude, f, n.size)
    ref = family.reference_filter(params, asm)
    if path == "feedback":
        out = [ref.step(0, -int(x), 0, 0) for x in e]
    else:
        out = [ref.step(int(x), 0, 0, 0) for x in e]
    basis = np.exp(-2j * np.pi * f * n[SKIP:])
    y = np.asarray(out[SKIP:], dtype=float) @ basis
    u = e[SKIP:].astype(float) @ basis
    return complex(y / u), max(abs(c) for c in out[SKIP:])


def check(family, params, asm, path: str, expected_params=None) -> list[float]:
    """Measure at every test frequency; assert within TOL of filter_response; the errors."""
    expected_params = expected_params or params
    q = output_step(family, asm)
    errors = []
    for f in FREQS:
        z = np.exp(2j * np.pi * f)
        want = complex(family.filter_response(expected_params, asm, z))
        amplitude = min(amplitude_cap(family, params, asm, f), TARGET / abs(want))
        got, peak = measure(family, params, asm, f, path, amplitude)
        for _ in range(5):
            if peak <= PEAK:
                break
            # The held derivative's aliases (PMD, DerivativeTime > 1) add to the peak: scale
            # the input down until the motor limit never clips.
            amplitude *= 0.7 * PEAK / peak
            got, peak = measure(family, params, asm, f, path, amplitude)
        assert peak <= PEAK and abs(want) * amplitude >= 4 * q / TOL, (
            "test design",
            peak,
            want,
            amplitude,
            f,
        )
        err = abs(got / want - 1)
        assert err <= TOL, (
            f"{params.model} {path} f={f}: measured gain {abs(got):.6g}, phase "
            f"{math.degrees(np.angle(got)):.3f} deg; filter_response {abs(want):.6g}, "
            f"{math.degrees(np.angle(want)):.3f} deg ({asm})"
        )
        errors.append(err)
    return errors


def settings_of(family):
    return family.assumptions_type.all_settings()


CASES = [
    pytest.param(model, i, id=f"{model}-{i}")
    for model in MODELS
    for i in range(len(settings_of(all_models()[model])))
]


@pytest.mark.parametrize(("model", "setting"), CASES)
def test_feedback_path_matches_filter_response(model, setting):
    """CP held, actual = -E: the loop's transfer, for every model and assumption setting."""
    family, model = get_chip(model)
    asm = settings_of(family)[setting]
    errors = check(family, linear_params(family, model, asm), asm, "feedback")
    assert max(errors) < TOL


@pytest.mark.parametrize(("model", "setting"), CASES)
def test_commanded_path(model, setting):
    """CP = E, actual 0. The same transfer where the filter acts on E alone (PMD, Parker
    ``error_rate``); without the velocity term where that acts on the actual position
    (PMAC Ixx31, Parker SGV under PK-A3 ``encoder``), which is why margins take the
    feedback path."""
    family, model = get_chip(model)
    asm = settings_of(family)[setting]
    params = linear_params(family, model, asm)
    expected = params
    if family.name == "pmac":
        # Feed-forward off, and the integrator running while the commanded position moves.
        params = params.replace(velocity_ff=0, acceleration_ff=0, integration_mode=0)
        expected = params.replace(derivative_gain=0)
    elif family.name == "parker6k" and asm.velocity_feedback == "encoder":
        expected = family.make_params(model, {**_flat(params), "sgv": 0})
    check(family, params, asm, "commanded", expected)
    if expected is not params:
        # The velocity term matters at these gains: the two paths differ measurably.
        z = np.exp(2j * np.pi * FREQS[-1])
        full = family.filter_response(params, asm, z)
        assert abs(family.filter_response(expected, asm, z) / full - 1) > 10 * TOL


def _flat(params) -> dict:
    from servogym.chips.parker6k._params import FIELDS

    return {name: getattr(params, name) for name in FIELDS if name != "model"}


@pytest.mark.parametrize("model", ["MC2100", "MC58000"])
@pytest.mark.parametrize("derivative_time", [1, 4, 10])
@pytest.mark.parametrize("mode", ["sample_difference", "cycle_difference"])
def test_pmd_derivative_time(model, derivative_time, mode):
    """PMD-A8 and DerivativeTime: the held derivative's LTI equivalent, d = 1, 4, 10."""
    family, model = get_chip(model)
    asm = family.assumptions_type(derivative_mode=mode)
    params = family.make_params(model, pmd_values(model, derivative_time))
    check(family, params, asm, "feedback")


@pytest.mark.parametrize("model", MODELS)
def test_only_the_linear_switches_change_the_response(model):
    """Each switch in LINEAR_SWITCHES moves C(z) by far more than TOL; every other leaves it
    exactly as it is (they act on rounding, limits, trips, feed-forward or the loop)."""
    family, model = get_chip(model)
    z = np.exp(2j * np.pi * np.array(FREQS))
    base = family.default_assumptions()
    params = linear_params(family, model, base)
    ref = family.filter_response(params, base, z)
    linear = LINEAR_SWITCHES[family.name]
    assert set(linear) <= set(family.assumptions_type.CHOICES)
    for asm in settings_of(family)[1:]:
        (name,) = [n for n in asm.CHOICES if getattr(asm, n) != getattr(base, n)]
        got = family.filter_response(params, asm, z)
        if name in linear and not (name == "biquad_format" and model != "MC58000"):
            assert np.max(np.abs(got / ref - 1)) > 5 * TOL, f"{name}={getattr(asm, name)}"
        else:
            np.testing.assert_array_equal(got, ref, err_msg=f"{name}={getattr(asm, name)}")


def test_every_family_has_its_linear_switches_listed():
    assert set(LINEAR_SWITCHES) == set(families())


# --- hand-computed cases -------------------------------------------------------------------


def _c(model: str, values: dict, z, **switches) -> complex:
    family, model = get_chip(model)
    params = family.make_params(model, values)
    return complex(family.filter_response(params, family.assumptions_type(**switches), z))


def test_pmd_by_hand():
    # Pure P: Kp Kout / 65536 = 100 * 13107 / 65536, at any z.
    p = dict(kp=100, ki=0, kd=0, kout=13107)
    for z in (1.0, -1.0, 1j, np.exp(0.3j)):
        assert _c("MC2100", p, z) == pytest.approx(1310700 / 65536, rel=1e-12)
    # Integral at z = -1: 1 / (1 - z^-1) = 1/2; Ki / 256 = 2; Kout / 65536 = 1/2: 0.5.
    i = dict(kp=0, ki=512, kd=0, kout=32768)
    assert _c("MC58000", i, -1.0) == pytest.approx(0.5)
    assert _c("MC58000", i, -1.0, integral_shift="0") == pytest.approx(128.0)
    # Derivative, DerivativeTime 2, at z = j (z^-1 = -j): hold (1 + z^-1)/2 = (1 - j)/2,
    # sample difference 1 - z^-2 = 2, so D = 1 - j; cycle difference 1 - z^-1 = 1 + j, D = 1.
    d = dict(kp=0, ki=0, kd=100, kout=32768, derivative_time=2)
    assert _c("MC58000", d, 1j) == pytest.approx(50 - 50j)
    assert _c("MC58000", d, 1j, derivative_mode="cycle_difference") == pytest.approx(50)
    # A biquad (1 + z^-1): words b0 = b1 = k = 16384, 1.0 in Q14 and 0.5 in Q15.
    b = dict(kp=100, ki=0, kd=0, kout=32768, biquad1_enable=1, biquad1_b1=16384)
    assert _c("MC58000", b, 1.0) == pytest.approx(100.0)  # 100 * 0.5 * 2
    assert _c("MC58000", b, -1.0) == pytest.approx(0.0)
    # Q15: k = 0.5, b0 + b1 = 1 at z = 1: 100 * 0.5 * 0.5 * 1.
    assert _c("MC58000", b, 1.0, biquad_format="q15") == pytest.approx(25.0)


def test_pmac_by_hand():
    # The spec's worked example (defaults): 2^-19 * 2000 * 96 at DC (no Ixx31 term there).
    assert _c("TurboPMAC2", {}, 1.0) == pytest.approx(2000 * 96 / 2**19)
    # At z = -1 the Ixx31 term is Ixx31 Ixx09 / 128 * 2 = 1280 * 96 / 128 * 2 = 1920.
    assert _c("TurboPMAC2", {}, -1.0) == pytest.approx(2000 * (96 + 1920) / 2**19)
    # Ixx33 = 2^22 (0.5 after 2^-23), Ixx31 = 0, at z = -1: previous z^-1/(1 - z^-1) = -1/2,
    # so 96 (1 - 0.25) = 72; current 1/(1 - z^-1) = 1/2, so 96 * 1.25 = 120.
    i = dict(integral_gain=2**22, derivative_gain=0)
    assert _c("GeoBrickLV", i, -1.0) == pytest.approx(2000 * 72 / 2**19)
    assert _c("GeoBrickLV", i, -1.0, integral_timing="current") == pytest.approx(2000 * 120 / 2**19)


def test_pmac_filter_period_includes_ixx60():
    """z is taken at the filter period: the servo period times Ixx60 + 1."""
    family, model = get_chip("TurboPMAC2")
    params = family.make_params(model, dict(servo_cycle_extension=1, integral_gain=100000))
    f = np.array([10.0, 100.0, 500.0])
    ts = 2 * params.servo_period_s
    assert family.sample_time_s(params) == pytest.approx(ts)
    np.testing.assert_allclose(
        family.filter_frequency_response(params, None, f),
        family.filter_response(params, None, np.exp(2j * np.pi * f * ts)),
        rtol=1e-12,
    )


def test_pmac_controller_response_is_filter_response():
    from servogym.chips.pmac import controller_response

    family, model = get_chip("TurboPMAC2")
    params = linear_params(family, model, family.default_assumptions())
    f = np.array([1.0, 50.0, 1000.0])
    np.testing.assert_allclose(
        controller_response(params, f).response, family.filter_frequency_response(params, None, f)
    )


def test_parker_by_hand():
    # SGP85 (uV): 8500 q per count, 32768 / 10^9 counts per q: 0.278528.
    p = dict(sgp=8500, sgv=0, sgi=0)
    assert _c("6250", p, 1j) == pytest.approx(0.278528)
    assert _c("6250", p, 1j, gain_unit="mV") == pytest.approx(278.528)
    assert _c("6250", p, 1j, dac_bits="16") == pytest.approx(0.278528)
    # SGV2.3 at z = -1, SSFR4 (160 us): 230 * 10^6 / 160 * 2 = 2,875,000 q: 94.208 counts.
    v = dict(sgp=0, sgv=230, sgi=0)
    assert _c("6K", v, -1.0) == pytest.approx(94.208)
    assert _c("6K", v, -1.0, velocity_feedback="error_rate") == pytest.approx(94.208)
    # SGI 10000.00 at z = -1: 10^6 * 160 / 10^6 = 160 q per count-sample, times 1/2
    # (current) or -1/2 (previous): +-80 q = +-0.00262144 counts.
    i = dict(sgp=0, sgv=0, sgi=1000000)
    assert _c("6K", i, -1.0) == pytest.approx(80 * 32768 / 1e9)
    assert _c("6K", i, -1.0, integral_timing="previous") == pytest.approx(-80 * 32768 / 1e9)


def test_parker_gains_in_force_at_reset():
    """A stored set switched in at tick 0 is the one in force; later switches are not."""
    from servogym.chips.parker6k import GainSet

    family, model = get_chip("6250")
    stored = GainSet(sgp=100, sgi=0, sgv=0, sgvf=0, sgaf=0)
    at0 = family.make_params(model, dict(sgp=8500, sgset=[stored], sgenb=[(0, 1)]))
    later = family.make_params(model, dict(sgp=8500, sgset=[stored], sgenb=[(5, 1)]))
    z = np.exp(0.1j)
    assert family.filter_response(at0, None, z) == pytest.approx(
        family.filter_response(at0.enable(1), None, z)
    )
    assert family.filter_response(later, None, z) != pytest.approx(
        family.filter_response(at0.enable(1), None, z)
    )


# --- the API -------------------------------------------------------------------------------


@pytest.mark.parametrize("model", MODELS)
def test_shape_dtype_and_bad_input(model):
    family, model = get_chip(model)
    params = family.make_params(model)
    z = np.exp(1j * np.linspace(0.01, 3.0, 6)).reshape(2, 3)
    out = family.filter_response(params, None, z)
    assert out.shape == (2, 3) and out.dtype == complex
    assert family.filter_response(params, family.default_assumptions(), z[0, 0]).shape == ()
    np.testing.assert_array_equal(out[1], family.filter_response(params, None, list(z[1])))
    other = next(f for f in families().values() if f is not family)
    with pytest.raises(TypeError, match=f"assumptions for a {family.name} chip must be"):
        family.filter_response(params, other.default_assumptions(), z)
    with pytest.raises(TypeError, match=f"params for a {family.name} chip must be"):
        family.filter_response(other.make_params(next(iter(other.models))), None, z)


@pytest.mark.parametrize("mode", ["sample_difference", "cycle_difference"])
def test_pmd_derivative_hold_closed_form_is_the_sum_of_its_phases(mode):
    # The hold is (1 + z^-1 + ... + z^-(d-1)) / d, computed in closed form as
    # (1 - z^-d) / (d (1 - z^-1)); here against the term-by-term sum at large d (where the
    # measured test above cannot go) and its limit 1 at z = 1 (so D(1) = 0 in both modes).
    from servogym.chips.pmd._response import derivative_response

    f = np.geomspace(1e-4, 0.4999, 200)
    zi = np.exp(-2j * np.pi * f)
    for d in (1, 2, 7, 64, 1000):
        hold = sum(zi**k for k in range(d)) / d
        diff = 1 - zi**d if mode == "sample_difference" else 1 - zi
        got = derivative_response(d, mode, zi)
        assert np.allclose(got, hold * diff, rtol=1e-9, atol=1e-12), d
    assert derivative_response(5, mode, np.array([1.0 + 0j]))[0] == 0
    # z = -1 (Nyquist), d = 4: the hold's four phases cancel: D = 0 in both modes.
    assert abs(derivative_response(4, mode, np.array([-1.0 + 0j]))[0]) < 1e-15


# --- the same response as polynomials ------------------------------------------------------


def random_set(family, model: str, rng, max_derivative_time: int = 32767):
    """Every tunable register drawn across its legal range (PMD DerivativeTime up to
    ``max_derivative_time``)."""
    space = family.parameter_space(model)
    values = {s.name: s.from_unit(float(rng.uniform(-1, 1))) for s in space.tunable()}
    if "derivative_time" in values:
        values["derivative_time"] = int(rng.integers(1, max_derivative_time + 1))
    return family.make_params(model, values)


@pytest.mark.parametrize(("model", "setting"), CASES)
def test_filter_polynomials_are_filter_response(model, setting):
    """``num(z^-1) / den(z^-1)`` equals ``filter_response`` to 1e-12 (relative to the
    terms' sizes) at random z
    (near the unit circle, where a long held derivative's ``z^-2d`` stays finite), for the
    test set and for random sets of every model and assumption setting; ``den[0] = 1``."""
    family, model = get_chip(model)
    asm = settings_of(family)[setting]
    rng = np.random.default_rng(setting)
    sets = [linear_params(family, model, asm)]
    sets += [random_set(family, model, rng, 40) for _ in range(4)]
    sets += [random_set(family, model, rng) for _ in range(2)]
    for params in sets:
        num, den = family.filter_polynomials(params, asm)
        assert num.dtype == den.dtype == np.float64 and den[0] == 1.0
        degree = num.size + den.size + 2 * getattr(params, "derivative_time", 0)
        radius = np.exp(rng.uniform(-1, 1, 16) * min(0.3, 2.0 / degree))
        z = radius * np.exp(1j * rng.uniform(-np.pi, np.pi, 16))
        want = family.filter_response(params, asm, z)
        x = 1 / z
        got = np.polynomial.polynomial.polyval(x, num) / np.polynomial.polynomial.polyval(x, den)
        # Relative to the sum of the terms' sizes (both forms cancel the same terms: a
        # large velocity gain times 1 - z^-1 near z = 1).
        terms = np.polynomial.polynomial.polyval(np.abs(x), np.abs(num))
        scale = np.abs(want) + terms / np.abs(np.polynomial.polynomial.polyval(x, den))
        err = np.abs(got - want)
        assert np.all(err <= 1e-12 * scale), (params, np.max(err / scale))


def test_filter_polynomials_by_hand():
    """PMD Kp 100, Ki 512 (2 after the shift), Kd 60 held over 3 cycles, Kout 16384 (1/4):
    ``C = (100 + 2 / (1 - x) + 60 (1 + x + x^2)(1 - x^3) / 3) / 4``; a zero filter is ``[0]``."""
    family, model = get_chip("MC2100")
    params = family.make_params(model, dict(kp=100, ki=512, kd=60, kout=16384, derivative_time=3))
    num, den = family.filter_polynomials(params, None)
    d = np.array([20.0, 20, 20, -20, -20, -20])
    want = np.convolve(np.concatenate([[100.0], np.zeros(5)]) + d, [1.0, -1.0])
    want[0] += 2.0
    np.testing.assert_allclose(num, want / 4, rtol=1e-15)
    np.testing.assert_array_equal(den, [1.0, -1.0])
    zero = family.make_params(model, dict(kp=0, ki=0, kd=0))
    num, den = family.filter_polynomials(zero, None)
    assert num.tolist() == [0.0] and den.tolist() == [1.0]
    with pytest.raises(TypeError, match="params for a pmd chip must be PMDParams"):
        family.filter_polynomials(object(), None)
