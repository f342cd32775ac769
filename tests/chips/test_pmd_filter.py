"""PMD filter: hand-computed cases from docs/chips/pmd.md, kernel == reference, legal ranges."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servogym.chips import ParameterError
from servogym.chips.pmd import CHIP_MODELS, FIELDS, PMDAssumptions, PMDParams, parameter_space
from servogym.chips.pmd._kernel import new_state, pmd_run
from servogym.chips.pmd._params import ASSUMPTION_CHOICES
from servogym.chips.pmd._reference import PMDReferenceFilter

ZERO = dict(
    kp=0,
    ki=0,
    kd=0,
    kvff=0,
    kaff=0,
    derivative_time=1,
    integration_limit=0,
    position_error_limit=2**31 - 1,
)


def both(params, errors, *, commanded=None, velocity=0, acceleration=0, **assumptions):
    """Run reference and kernel over a sequence of errors (actual = commanded - error)."""
    asm = PMDAssumptions(**assumptions)
    n = len(errors)
    cp = np.zeros(n, np.int64) if commanded is None else np.asarray(commanded, np.int64)
    ap = cp - np.asarray(errors, np.int64)
    v = np.full(n, velocity, np.int64)
    acc = np.full(n, acceleration, np.int64)
    ref = PMDReferenceFilter(params, asm)
    expected = [
        ref.step(int(c), int(a), int(vv), int(aa))
        for c, a, vv, aa in zip(cp, ap, v, acc, strict=True)
    ]
    got = pmd_run(
        new_state(), params.to_array(), asm.to_array(), cp, ap, v, acc, np.zeros(n, np.int64)
    )
    assert got.tolist() == expected, "kernel differs from reference"
    return expected


def pmd(**kw) -> PMDParams:
    return PMDParams(**{**ZERO, "kout": 16384, **kw})


# --- hand-computed cases: expected numbers written from the spec, not from the code --------


def test_proportional_only():
    # U = 40 * 100 = 4000; Y = 4000 * 16384 >> 16 = 1000.
    assert both(pmd(kp=40), [100, -100, 0]) == [1000, -1000, 0]


def test_integral_reaches_its_limit():
    # I = 100, 200, 250 (limit), 250; ki*I >> 8 = I for ki = 256; Y = I/4, floor(62.5) = 62.
    p = pmd(ki=256, integration_limit=250)
    assert both(p, [100, 100, 100, 100]) == [25, 50, 62, 62]
    # The sum is limited on the negative side too, and unwinds from the limit at once.
    assert both(p, [-300, -300, 100]) == [-63, -63, -38]


def test_derivative_time_1():
    # D = E_n - E_{n-1} every cycle: 0, 10, 20, 0, -10; U = 4 D; Y = U / 4.
    assert both(pmd(kd=4), [0, 10, 30, 30, 20]) == [0, 10, 20, 0, -10]


def test_derivative_time_5_holds_between_samples():
    # E_n = 3n. Samples at n = 0, 5, 10: D = 0, 15 - 0, 30 - 15; held between; Y = 4 D / 4.
    errors = [3 * n for n in range(12)]
    assert both(pmd(kd=4, derivative_time=5), errors) == [0] * 5 + [15] * 5 + [15] * 2
    # PMD-A8 alternative: the difference over one cycle, taken at the sample instants.
    got = both(pmd(kd=4, derivative_time=5), errors, derivative_mode="cycle_difference")
    assert got == [0] * 5 + [3] * 5 + [3] * 2


def test_derivative_saturates_to_16_bits():
    # D = 40000 - 0 saturates to 32767 (PMD-A7 default); Y = 32767 * 16384 >> 16 = 8191.
    p = pmd(kd=1, motor_limit=32767)
    assert both(p, [40000]) == [8191]
    assert both(p, [40000], derivative_saturation="none") == [10000]


def test_kout_scaling_rounds_negative_values():
    # -100 * 3 = -300; -300 / 65536 = -0.0046: floor -1, trunc 0.
    assert both(pmd(kp=1, kout=3), [-100]) == [-1]
    assert both(pmd(kp=1, kout=3), [-100], rounding="trunc") == [0]
    # -30000 * 32767 = -983,010,000; / 65536 = -14999.54: floor -15000, trunc -14999.
    p = pmd(kp=1, kout=32767)
    assert both(p, [-30000]) == [-15000]
    assert both(p, [-30000], rounding="trunc") == [-14999]
    assert both(p, [30000]) == [14999]


def test_bias_and_motor_limit_order():
    # Y = 100 * E / 4 = 25 E. E = 1000: Y = 25000, + bias 10000.
    p = pmd(kp=100, bias=10000, motor_limit=30000)
    assert both(p, [1000, -1000]) == [30000, -15000]
    # PMD-A5 alternative: limit Y first (25000), add bias (35000), saturate to 16 bits.
    assert both(p, [1000, -1000], bias_order="limit_then_bias") == [32767, -15000]
    # With zero error the command is the bias alone.
    assert both(p, [0]) == [10000]


def test_motion_error_on_the_error_limit():
    p = pmd(kp=40, position_error_limit=100)
    # |E| = 100 does not exceed 100; 101 does: from then on the command is 0 (latched).
    assert both(p, [100, 101, 0, 50]) == [1000, 0, 0, 0]
    assert both(p, [100, 0], error_limit_compare="greater_equal") == [0, 0]
    assert both(p, [100, 101, 50], motion_error="flag_only") == [1000, 1010, 500]
    ref = PMDReferenceFilter(p)
    ref.step(0, -101, 0, 0)
    assert ref.motion_error


def test_32_bit_position_wrap():
    # Commanded has wrapped past 2^31 - 1 to -2^31 + 5; actual is 2^31 - 5: the error is +10.
    p = pmd(kp=4)
    cp = np.array([-(2**31) + 5], np.int64)
    ap = np.array([2**31 - 5], np.int64)
    ref = PMDReferenceFilter(p).step(int(cp[0]), int(ap[0]), 0, 0)
    z = np.zeros(1, np.int64)
    kern = pmd_run(new_state(), p.to_array(), PMDAssumptions().to_array(), cp, ap, z, z, z.copy())
    assert ref == kern[0] == 10


def test_feedforward_input_formats():
    # V = 3.5 counts/cycle = 229376 in 16.16; kvff = 10; kout 16384 divides by 4 afterwards.
    p = pmd(kvff=40)
    assert both(p, [0], velocity=229376) == [30]  # 40 * 3 / 4
    assert both(p, [0], velocity=229376, feedforward_input="fraction") == [35]  # 40*3.5/4
    assert both(p, [0], velocity=-229376) == [-40]  # floor(-3.5) = -4
    assert both(p, [0], velocity=-229376, rounding="trunc") == [-30]
    # Acceleration 2.0 counts/cycle^2, kaff 8: 16 / 4 = 4.
    assert both(pmd(kaff=8), [0], acceleration=2 * 65536) == [4]


def test_kout_on_feedforward_switch():
    # kout 16384: PID part scaled by 1/4, feed-forward 40*3 = 120 added after when "no".
    p = pmd(kp=40, kvff=40)
    assert both(p, [100], velocity=3 * 65536) == [1030]
    assert both(p, [100], velocity=3 * 65536, kout_scales_feedforward="no") == [1120]


def test_accumulator_saturates_before_kout():
    # kp E = 32767 * 70000 = 2,293,690,000 > 2^31 - 1. kout = 1 divides by 65536.
    # sat32: 2,147,483,647 >> 16 = 32767; sat48: 2,293,690,000 >> 16 = 34998; bias -20000.
    p = pmd(kp=32767, kout=1, bias=-20000)
    assert both(p, [70000]) == [12767]
    assert both(p, [70000], accumulator="sat48") == [14998]


def test_magellan_biquad_identity_and_gain():
    base = dict(model="MC58000", biquad1_enable=1)
    # b0 = 1.0, k = 1.0 (Q14): a pass-through.
    assert both(pmd(kp=40, **base), [100]) == [1000]
    # k = 0.5: halves the output; b1 = 1.0 adds the previous input.
    p = pmd(kp=40, biquad1_k=8192, biquad1_b1=16384, **base)
    assert both(p, [100, 100]) == [500, 1000]


def test_non_magellan_model_refuses_biquads():
    with pytest.raises(ParameterError, match="biquad1_enable exists only on models with biquad"):
        PMDParams(model="MC2100", biquad1_enable=1)


# --- kernel == reference, property tests --------------------------------------------------


@st.composite
def legal_params(draw, model=None):
    model = model or draw(st.sampled_from(sorted(CHIP_MODELS)))
    space = parameter_space(model)
    values = {}
    for name, spec in space.items():
        if spec.log and spec.high > 1000:
            # Realistic magnitudes most of the time, the extremes sometimes.
            values[name] = draw(
                st.one_of(
                    st.integers(spec.low, min(spec.high, 2000)),
                    st.sampled_from([spec.low, spec.high]),
                    st.integers(spec.low, spec.high),
                )
            )
        else:
            values[name] = draw(st.integers(spec.low, spec.high))
    return PMDParams(model=model, **values)


def inputs(seed: int, n: int):
    """Commanded/actual/velocity/acceleration sequences: small errors, wraps and extremes."""
    rng = np.random.default_rng(seed)
    scale = rng.choice([10, 1000, 100_000, 2**31])
    cp = rng.integers(-(2**31), 2**31, n)
    err = np.clip(np.cumsum(rng.integers(-scale // 10 - 1, scale // 10 + 2, n)), -scale, scale)
    ap = (cp - err + 2**31) % 2**32 - 2**31
    v = rng.integers(-(2**31), 2**31, n) >> rng.integers(0, 20)
    a = rng.integers(-(2**31), 2**31, n) >> rng.integers(0, 24)
    return cp, ap, v, a


TICKS = 500
SETTINGS = PMDAssumptions.all_settings()


@pytest.mark.parametrize(
    "asm",
    SETTINGS,
    ids=["default", *[f"{k}={v}" for k, c in ASSUMPTION_CHOICES.items() for v in c[1:]]],
)
@settings(max_examples=10, deadline=None)
@given(params=legal_params(), seed=st.integers(0, 2**32 - 1))
def test_kernel_matches_reference_every_assumption(asm, params, seed):
    # 25 settings x 10 examples x 500 ticks = 125,000 ticks per run of the suite.
    cp, ap, v, a = inputs(seed, TICKS)
    ref = PMDReferenceFilter(params, asm)
    expected = [
        ref.step(int(c), int(x), int(y), int(z)) for c, x, y, z in zip(cp, ap, v, a, strict=True)
    ]
    got = pmd_run(
        new_state(), params.to_array(), asm.to_array(), cp, ap, v, a, np.zeros(TICKS, np.int64)
    )
    np.testing.assert_array_equal(got, expected)
    assert all(-32768 <= c <= 32767 for c in expected)


@settings(max_examples=30, deadline=None)
@given(
    params=legal_params(),
    seed=st.integers(0, 2**32 - 1),
    choice=st.fixed_dictionaries({k: st.sampled_from(v) for k, v in ASSUMPTION_CHOICES.items()}),
)
def test_kernel_matches_reference_mixed_assumptions(params, seed, choice):
    asm = PMDAssumptions(**choice)
    cp, ap, v, a = inputs(seed, 200)
    ref = PMDReferenceFilter(params, asm)
    expected = [
        ref.step(int(c), int(x), int(y), int(z)) for c, x, y, z in zip(cp, ap, v, a, strict=True)
    ]
    got = pmd_run(
        new_state(), params.to_array(), asm.to_array(), cp, ap, v, a, np.zeros(200, np.int64)
    )
    np.testing.assert_array_equal(got, expected)


def test_update_keeps_state():
    p1, p2 = pmd(ki=256, integration_limit=1000), pmd(ki=512, integration_limit=1000)
    ref = PMDReferenceFilter(p1)
    ref.step(100, 0, 0, 0)
    ref.update(p2)
    # I = 200 after the second cycle; 512 * 200 >> 8 = 400; / 4 = 100.
    assert ref.step(100, 0, 0, 0) == 100


# --- legal ranges ------------------------------------------------------------------------


def illegal_cases():
    for model in sorted(CHIP_MODELS):
        for name, spec in parameter_space(model).items():
            for value in (spec.low - 1, spec.high + 1, 1.5, True, "7"):
                yield pytest.param(model, name, spec, value, id=f"{model}-{name}-{value!r}")


@pytest.mark.parametrize("model,name,spec,value", list(illegal_cases()))
def test_every_illegal_value_is_rejected_with_its_range(model, name, spec, value):
    with pytest.raises(ParameterError, match=f"{spec.low} <= {name} <= {spec.high}") as info:
        PMDParams(model=model, **{name: value})
    assert repr(value) in str(info.value) or str(value) in str(info.value)


def test_range_edges_are_legal():
    for model in CHIP_MODELS:
        space = parameter_space(model)
        PMDParams(model=model, **{n: s.low for n, s in space.items()})
        PMDParams(model=model, **{n: s.high for n, s in space.items()})


def test_unknown_parameter_suggests_close_names():
    with pytest.raises(ParameterError, match="Did you mean kp"):
        PMDParams.from_dict({"model": "MC2100", "kpp": 1})


def test_unknown_model_and_assumption_are_named():
    with pytest.raises(ParameterError, match="MC2100"):
        PMDParams(model="MC2101")
    with pytest.raises(ParameterError, match="PMD-A1 rounding must be one of 'floor', 'trunc'"):
        PMDAssumptions(rounding="nearest")


def test_to_array_follows_fields():
    p = PMDParams(model="MC58000", kp=7, biquad2_k=99)
    arr = p.to_array()
    assert arr[FIELDS.index("kp")] == 7 and arr[FIELDS.index("biquad2_k")] == 99
    assert dataclasses.replace(p, kp=8).kp == 8
