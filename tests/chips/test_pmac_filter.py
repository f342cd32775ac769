"""PMAC filter: hand-computed cases from docs/chips/pmac.md, kernel == reference, legal ranges."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servogym.chips import ParameterError
from servogym.chips.pmac import (
    ASSUMPTION_CHOICES,
    CHIP_MODELS,
    FIELDS,
    I_VARIABLES,
    PMACAssumptions,
    PMACParams,
    PMACReferenceFilter,
    parameter_space,
)
from servogym.chips.pmac._kernel import S_TRIPPED, STATE_SIZE, new_state, pmac_run, pmac_step

# "Unit" registers: Ixx08 = 8 and Ixx30 = 2^21 make O = 32 Y and DAC = floor(Y / 8), so the
# output is FEd + IO + floor((FF - D) / 8) with the error in 1/32 count (spec section 3).
UNIT = dict(
    position_loop_scale=8,
    velocity_loop_scale=1,
    fatal_following_error_limit=0,
    proportional_gain=2**21,
    derivative_gain=0,
    velocity_ff=0,
    integral_gain=0,
    integration_mode=0,
    acceleration_ff=0,
    deadband_gain=0,
    deadband_size=0,
    output_limit=32767,
)


def pmac(**kw) -> PMACParams:
    return PMACParams(**{**UNIT, **kw})


def both(params, commanded, actual=None, fraction=None, **assumptions):
    """Run reference and kernel over input sequences; they must agree; return the outputs."""
    asm = PMACAssumptions(**assumptions)
    cp = np.asarray(commanded, np.int64)
    n = cp.shape[0]
    ap = np.zeros(n, np.int64) if actual is None else np.asarray(actual, np.int64)
    fr = np.zeros(n, np.int64) if fraction is None else np.asarray(fraction, np.int64)
    expected = PMACReferenceFilter(params, asm).run(cp, ap, fr)
    got = pmac_run(
        new_state(), params.to_array(), asm.to_array(), cp, ap, fr, np.zeros(n, np.int64),
        np.zeros(n, np.int64),
    )  # fmt: skip
    assert got.tolist() == expected, "kernel differs from reference"
    return expected


# --- hand-computed cases: expected numbers written from the spec, not from the code --------


def test_worked_example_with_defaults():
    # Defaults, FE = 100 counts at rest (second update): FE = 3200, Y = 96 * 3200 = 307200,
    # O = 2000 * 307200 / 2^16 = 9375, DAC = 9375 >> 8 = 36 (the manual's equation: 36.6).
    # The first update sees the step as commanded velocity (PMAC-A13): CV32 = 3200,
    # CV = 96 * 3200 = 307200, FF = 1280 * 307200 / 128 = 3,072,000, Y = 3,379,200,
    # O = 103,125, DAC = 402.
    p = PMACParams()
    assert both(p, [100, 100]) == [402, 36]
    # Negative: O = -103,125 and -9375; the DAC bits floor: -402.8 -> -403, -36.6 -> -37,
    # also with truncating shifts (the bit selection always floors).
    assert both(p, [-100, -100]) == [-403, -37]
    assert both(p, [-100, -100], rounding="trunc") == [-403, -37]
    # PMAC-A13 alternative: no commanded velocity in the first update.
    assert both(p, [100, 100], first_cycle="commanded") == [36, 36]


def test_output_word_rounding():
    # Ixx08 = 1, Ixx30 = 513, FE = -1024 counts: Y = -32768, Ixx30 Y / 2^16 = -256.5:
    # floor -257 -> DAC -257 >> 8 = -2; trunc -256 -> DAC -1. Positive: 256 -> 1.
    p = pmac(position_loop_scale=1, proportional_gain=513)
    assert both(p, [-1024]) == [-2]
    assert both(p, [-1024], rounding="trunc") == [-1]
    assert both(p, [1024]) == [1]


def test_integrator_timing_and_limit():
    # Ixx33 = 2^20, FE = 1 count: each integration adds 2^20 * 32 = 2^25 to IS, IO = IS >> 23
    # grows by 4. "previous": the output of update n uses n integrations: 32, 36, 40, 44.
    p = pmac(integral_gain=2**20)
    assert both(p, [1] * 4) == [32, 36, 40, 44]
    assert both(p, [1] * 4, integral_timing="current") == [36, 40, 44, 48]
    # Ixx63 = 4: L = 4 * 2^24 = 2^26, IO at most 8.
    p = pmac(integral_gain=2**20, integration_limit=4)
    assert both(p, [1] * 5) == [32, 36, 40, 40, 40]
    assert both(p, [1] * 4, integral_timing="current") == [36, 40, 40, 40]
    # Ixx63 = 0 forces zero integral output.
    assert both(pmac(integral_gain=2**20, integration_limit=0), [1] * 3) == [32, 32, 32]


def test_negative_integration_limit_trips():
    # Ixx63 = -4: after two integrations |IS| = 2^26 >= 4 * 2^24: the third update trips.
    p = pmac(integral_gain=2**20, integration_limit=-4)
    assert both(p, [1] * 4) == [32, 36, 0, 0]
    assert both(p.replace(output_bias=7), [1] * 4, trip_action="kill_bias") == [39, 43, 7, 7]
    assert both(p, [1] * 4, trip_action="flag_only") == [32, 36, 40, 40]
    ref = PMACReferenceFilter(p)
    ref.run([1] * 3, [0] * 3, [0] * 3)
    assert ref.motion_error


def test_integration_mode_holds_while_moving():
    # Commanded 0, 1, 1, 1 counts, actual 0. Update 0: CV32 = 0, FE = 0. Update 1: CV32 = 32,
    # FE = 32: with Ixx34 = 1 no integration (held). Updates 2, 3: CV32 = 0, integrating.
    p = pmac(integral_gain=2**20, integration_mode=1)
    assert both(p, [0, 1, 1, 1]) == [0, 32, 32, 36]
    assert both(p.replace(integration_mode=0), [0, 1, 1, 1]) == [0, 32, 36, 40]


def test_anti_windup():
    # Ixx69 = 40. FE = 1 count: 32, 36, 40 (40 is not clamped), then 44 -> 40 limited: the
    # increment would grow IS, dropped; IO stays 12. FE = -2 counts: -64 + 12 = -52 -> -40
    # limited; the increment shrinks IS to 2^25 (IO 4): kept under "hold_growth". Next:
    # -60 -> -40, IS -> -2^25 (same magnitude, kept); then -68 -> -40, growth dropped.
    # FE = 0 then shows IO: -4 ("hold_growth") or 12 ("freeze": every limited update drops).
    p = pmac(integral_gain=2**20, output_limit=40)
    errors = [1, 1, 1, 1, 1, -2, -2, -2, -2, 0, 0]
    common = [32, 36, 40, 40, 40, -40, -40, -40, -40]
    assert both(p, errors) == [*common, -4, -4]
    assert both(p, errors, anti_windup="freeze") == [*common, 12, 12]


def test_derivative_on_actual_velocity():
    # Ixx31 = 1024, Ixx09 = 1: AV = 32 dA, D = 1024 * AV / 128 = 256 dA, DAC = -D / 8 = -32 dA.
    p = pmac(derivative_gain=1024)
    assert both(p, [0, 0, 10, 30], [0, 0, 10, 30]) == [0, 0, -320, -640]
    # A negative Ixx30 inverts the output polarity.
    p = p.replace(proportional_gain=-(2**21))
    assert both(p, [0, 0, 10, 30], [0, 0, 10, 30]) == [0, 0, 320, 640]


def test_feedforward_from_commanded_position_differences():
    # Ixx32 = 128: FF = 128 * 8 CV32 / 128 = 8 CV32, DAC adds CV32. Commanded 0, 10, 20:
    # FE32 = 0, 320, 640; CV32 = 0, 320, 320 -> 0, 640, 960.
    p = pmac(velocity_ff=128)
    assert both(p, [0, 10, 20]) == [0, 640, 960]
    # Ixx35 = 128 adds CA = CV - CV_prev (internal units) / 8: 0, 320, 0.
    assert both(p.replace(acceleration_ff=128), [0, 10, 20]) == [0, 960, 960]
    # A fraction: CP = 0 + 16/32 count. FE32 = 16; CV32 = 16 in update 0, then 0.
    assert both(p, [0, 0], fraction=[16, 16]) == [32, 16]
    assert both(p, [0, 0], fraction=[16, 16], first_cycle="commanded") == [16, 16]
    # Only the fraction's low 5 bits are read: 48 is 16.
    assert both(p, [0, 0], fraction=[48, 48]) == [32, 16]


def test_feedforward_rounding():
    # Ixx32 = 1, CP = -1/32 count: FE32 = -1, CV32 = -1, CV = -8, FF = shr(-8, 7):
    # floor -1, trunc 0. Y = 8 * (-1) + FF = -9 or -8; DAC = floor(Y / 8) = -2 or -1.
    p = pmac(velocity_ff=1)
    assert both(p, [-1], fraction=[31]) == [-2]
    assert both(p, [-1], fraction=[31], rounding="trunc") == [-1]


def test_deadband():
    # Ixx65 = 32 (2 counts: B = 64 in 1/32 count), Ixx64 = -16: a true deadband.
    p = pmac(deadband_size=32, deadband_gain=-16)
    assert both(p, [1]) == [0]  # inside: 32 * 0 / 16
    assert both(p, [2]) == [0]  # on the edge: outside, 64 - 64
    assert both(p, [3]) == [32]  # outside: 96 + shr(-16 * 64, 4) = 96 - 64
    assert both(p, [-3]) == [-32]
    assert both(p, [3], deadband_outside="plain") == [96]
    # Ixx64 = 16 doubles the gain inside; outside the offset is +64.
    p = pmac(deadband_size=32, deadband_gain=16)
    assert both(p, [1]) == [64]
    assert both(p, [3]) == [160]
    # Rounding inside: Ixx64 = -8, FE32 = -1: shr(-1 * 8, 4) = -1 (floor) or 0 (trunc).
    p = pmac(deadband_size=32, deadband_gain=-8)
    assert both(p, [-1], fraction=[31]) == [-1]
    assert both(p, [-1], fraction=[31], rounding="trunc") == [0]


def test_big_step_limit():
    # Ixx67 = 16 (1 count = 32 in 1/32 count): an error of 100 counts enters as 1 count.
    p = pmac(big_step_limit=16)
    assert both(p, [100]) == [32]
    assert both(p, [-100]) == [-32]
    assert both(pmac(big_step_limit=0), [100]) == [0]


def test_fatal_following_error():
    # Ixx11 = 160 (1/16 count) = 320 in 1/32 count: FE32 = 320 does not exceed it, 321 does.
    p = pmac(fatal_following_error_limit=160)
    assert both(p, [10, 10, 0], fraction=[0, 1, 0]) == [320, 0, 0]
    assert both(p, [10, 0], trip_compare="greater_equal") == [0, 0]
    assert both(p, [10, 10, 0], fraction=[0, 1, 0], trip_action="flag_only") == [320, 321, 0]
    # Ixx11 = 0 disables the check.
    assert both(pmac(), [1000]) == [32000]
    state = new_state()
    pmac_step(state, p.to_array(), PMACAssumptions().to_array(), 11, 0, 0, 0)
    assert state[S_TRIPPED] == 1 and state.shape[0] == STATE_SIZE


def test_bias_and_limit_order():
    # FE = 1000 counts -> 32000; Ixx69 = 20000, Ixx29 = 5000.
    p = pmac(output_limit=20000, output_bias=5000)
    assert both(p, [1000, 1000]) == [25000, 25000]
    assert both(p, [1000], bias_order="bias_then_limit") == [20000]
    assert both(p, [-1000]) == [-15000]
    assert both(p, [-1000], bias_order="bias_then_limit") == [-20000]
    assert both(p, [0]) == [5000]
    # Saturation: FE = 2000 counts makes O = 256 * 64000, beyond 24 bits: O = 2^23 - 1,
    # DAC 32767, + bias 32767 -> sat16 32767. Negative: DAC -32768 -> limit -32767 -> 0.
    p = pmac(output_bias=32767)
    assert both(p, [2000]) == [32767]
    assert both(p, [-2000]) == [0]


def test_friction_feedforward_order():
    # CP = 1/32 count: FE32 = 1, CV32 = 1 (update 0) then 0. Ixx68 = 1000, Ixx69 = 500.
    p = pmac(friction_ff=1000, output_limit=500)
    assert both(p, [0, 0], fraction=[1, 1]) == [500, 1]
    assert both(p, [0, 0], fraction=[1, 1], friction_order="after_limit") == [1001, 1]
    assert both(p, [-1], fraction=[31]) == [-500]
    assert both(p, [-1], fraction=[31], friction_order="after_limit") == [-1001]


def test_notch():
    # FE = 1 count: O = 256 * 32 = 8192 every update. n1 = 1.0: w = x + x1 -> 32, 64, 64.
    p = pmac(notch_n1=2**22)
    for form in ("df1", "df2"):
        for position in ("after_kp", "before_kp"):
            assert both(p, [1] * 3, notch_form=form, notch_position=position) == [32, 64, 64]
    # d1 = -0.5: w = x + w1 / 2: 8192, 12288, 14336 -> 32, 48, 56.
    p = pmac(notch_d1=-(2**21))
    assert both(p, [1] * 3) == [32, 48, 56]
    assert both(p, [1] * 3, notch_form="df2") == [32, 48, 56]


def test_32_bit_position_wrap():
    # Commanded has wrapped past 2^31 - 1 to -2^31 + 5; actual is 2^31 - 5: FE = +10 counts.
    assert both(pmac(), [-(2**31) + 5], [2**31 - 5]) == [320]


def test_velocity_word_width():
    # Ixx08 = 1, Ixx30 = 2^16 (O = Y, DAC = Y >> 8), Ixx32 = 1 (FF = CV >> 7); commanded =
    # actual, moving 2^19 counts in update 1: CV = 32 * 2^19 = 2^24, saturated to 2^23 - 1
    # in a 24-bit word: FF = 65535, DAC 255; in a 32-bit word FF = 131072, DAC 512.
    p = pmac(position_loop_scale=1, proportional_gain=2**16, velocity_ff=1)
    assert both(p, [0, 2**19], [0, 2**19]) == [0, 255]
    assert both(p, [0, 2**19], [0, 2**19], velocity_words="s32") == [0, 512]


def test_update_keeps_state():
    p1 = pmac(integral_gain=2**20)
    ref = PMACReferenceFilter(p1)
    ref.step(1, 0)
    ref.update(p1.replace(proportional_gain=2**22))
    # IO = 4 after one integration; with twice the gain the output doubles: 2 * (32 + 4).
    assert ref.step(1, 0) == 72
    ref.reset()
    assert ref.integrator == 0 and ref.cycle == 0


# --- kernel == reference, property tests --------------------------------------------------


@st.composite
def legal_params(draw, model=None):
    model = model or draw(st.sampled_from(sorted(CHIP_MODELS)))
    space = parameter_space(model)
    values = {}
    for name, spec in space.items():
        if spec.high > 1000:
            # Realistic magnitudes most of the time, the extremes sometimes.
            small = st.integers(max(spec.low, -3000), min(spec.high, 3000))
            values[name] = draw(
                st.one_of(
                    small,
                    small,
                    st.sampled_from([spec.low, spec.high, spec.default]),
                    st.integers(spec.low, spec.high),
                ),
                label=name,
            )
        else:
            values[name] = draw(st.integers(spec.low, spec.high), label=name)
    return PMACParams(model=model, **values)


def inputs(seed: int, n: int):
    """Commanded / actual / fraction sequences: holds and ramps, small errors, wraps, extremes."""
    rng = np.random.default_rng(seed)
    scale = int(rng.choice([3, 300, 30_000, 2**31]))
    steps = rng.integers(-scale // 3 - 1, scale // 3 + 2, n)
    steps[rng.random(n) < 0.4] = 0  # holds: the commanded velocity is zero
    cp = (int(rng.integers(-(2**31), 2**31)) + np.cumsum(steps) + 2**31) % 2**32 - 2**31
    err = np.clip(np.cumsum(rng.integers(-scale // 10 - 1, scale // 10 + 2, n)), -scale, scale)
    ap = (cp - err + 2**31) % 2**32 - 2**31
    frac = rng.integers(0, 64 if rng.random() < 0.2 else 32, n)
    if rng.random() < 0.3:
        frac[:] = frac[0]
    return cp.astype(np.int64), ap.astype(np.int64), frac.astype(np.int64)


TICKS = 700
SETTINGS = PMACAssumptions.all_settings()


def run_both(params, asm, cp, ap, fr):
    expected = PMACReferenceFilter(params, asm).run(cp, ap, fr)
    n = cp.shape[0]
    got = pmac_run(
        new_state(), params.to_array(), asm.to_array(), cp, ap, fr, np.zeros(n, np.int64),
        np.zeros(n, np.int64),
    )  # fmt: skip
    np.testing.assert_array_equal(got, expected)
    assert all(-32768 <= c <= 32767 for c in expected)


@pytest.mark.parametrize(
    "asm",
    SETTINGS,
    ids=["default", *[f"{k}={v}" for k, c in ASSUMPTION_CHOICES.items() for v in c[1:]]],
)
@settings(max_examples=10, deadline=None)
@given(params=legal_params(), seed=st.integers(0, 2**32 - 1))
def test_kernel_matches_reference_every_assumption(asm, params, seed):
    # 15 settings x 10 examples x 700 updates = 105,000 updates per run of the suite.
    run_both(params, asm, *inputs(seed, TICKS))


@settings(max_examples=30, deadline=None)
@given(
    params=legal_params(),
    seed=st.integers(0, 2**32 - 1),
    choice=st.fixed_dictionaries({k: st.sampled_from(v) for k, v in ASSUMPTION_CHOICES.items()}),
)
def test_kernel_matches_reference_mixed_assumptions(params, seed, choice):
    run_both(params, PMACAssumptions(**choice), *inputs(seed, 200))


def test_kernel_matches_reference_at_the_extremes():
    # Every register at its low end, then its high end, under every setting: the widths of
    # section 3 must hold (the kernel's int64 never overflows where Python's ints would not).
    space = parameter_space("TurboPMAC2")
    for end in ("low", "high"):
        p = PMACParams(**{n: getattr(s, end) for n, s in space.items()})
        for asm in SETTINGS:
            run_both(p, asm, *inputs(7, 100))


# --- legal ranges ------------------------------------------------------------------------


def illegal_cases():
    for model in sorted(CHIP_MODELS):
        for name, spec in parameter_space(model).items():
            for value in (spec.low - 1, spec.high + 1, 1.5, True, "7"):
                yield pytest.param(model, name, spec, value, id=f"{model}-{name}-{value!r}")


@pytest.mark.parametrize("model,name,spec,value", list(illegal_cases()))
def test_every_illegal_value_is_rejected_with_its_range(model, name, spec, value):
    with pytest.raises(ParameterError, match=f"{spec.low} <= {name} <= {spec.high}") as info:
        PMACParams(model=model, **{name: value})
    assert repr(value) in str(info.value) or str(value) in str(info.value)


def test_range_edges_are_legal():
    for model in CHIP_MODELS:
        space = parameter_space(model)
        PMACParams(model=model, **{n: s.low for n, s in space.items()})
        PMACParams(model=model, **{n: s.high for n, s in space.items()})


def test_unknown_parameter_suggests_close_names():
    with pytest.raises(ParameterError, match="Did you mean proportional_gain"):
        PMACParams.from_dict({"model": "TurboPMAC2", "proportional_gan": 1})


def test_unknown_model_and_assumption_are_named():
    with pytest.raises(ParameterError, match=r"unknown PMAC chip model 'GeoBrick'.*GeoBrickLV"):
        PMACParams(model="GeoBrick")
    with pytest.raises(ParameterError, match="PMAC-A1 rounding must be one of 'floor', 'trunc'"):
        PMACAssumptions(rounding="nearest")
    assert PMACParams(model="geobricklv").model == "GeoBrickLV"


def test_to_array_follows_fields_and_ivar_table():
    p = PMACParams(proportional_gain=7, servo_clock_divider=1)
    arr = p.to_array()
    assert arr.dtype == np.int64 and arr.shape == (len(FIELDS),)
    assert arr[FIELDS.index("proportional_gain")] == 7
    assert arr[FIELDS.index("servo_clock_divider")] == 1
    assert dataclasses.replace(p, proportional_gain=8).proportional_gain == 8
    # One I-variable per register, in I-variable order, and the brief's names.
    assert list(I_VARIABLES) == list(FIELDS)
    assert list(I_VARIABLES.values()) == sorted(I_VARIABLES.values())
    assert {I_VARIABLES[f]: f for f in I_VARIABLES}[30] == "proportional_gain"
    assert [I_VARIABLES[f] for f in ("notch_n1", "notch_n2", "notch_d1", "notch_d2")] == [
        36,
        37,
        38,
        39,
    ]


def test_sample_time_and_motor_limit():
    p = PMACParams()
    # (2 * 6527 + 3) * 1 * 4 = 52228 master-clock cycles of 1/117.9648 MHz = 442.742 us.
    assert p.servo_period_ticks == 52228
    assert p.sample_time_s == pytest.approx(442.742e-6, abs=1e-9)
    assert p.replace(servo_cycle_extension=3).sample_time_s == pytest.approx(4 * 442.742e-6)
    assert p.replace(servo_clock_divider=1).sample_time_us == pytest.approx(221.371, abs=1e-3)
    assert p.motor_limit == 20480 == p.output_limit
