"""Parker 6000 PIV&F: hand-computed cases from docs/chips/parker6k.md, kernel == reference."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servogym.chips import ParameterError
from servogym.chips.parker6k import (
    CHIP_MODELS,
    GAIN_FIELDS,
    MAX_GAIN_SETS,
    S_TRIPPED,
    GainSet,
    Parker6kAssumptions,
    Parker6kParams,
    Parker6kReferenceFilter,
    new_state,
    parameter_space,
    parker6k_run,
    parker6k_step,
)
from servogym.chips.parker6k._params import A_INDEX, ASSUMPTION_CHOICES, GAIN_MAX

ZERO = dict(sgp=0, sgi=0, sgv=0, sgvf=0, sgaf=0)


def both(params, commanded, actual, velocity=None, acceleration=None, **assumptions):
    """Run reference and kernel over the same inputs; they must agree exactly."""
    asm = Parker6kAssumptions(**assumptions)
    n = len(commanded)
    cp = np.asarray(commanded, np.int64)
    ap = np.asarray(actual, np.int64)
    v = np.zeros(n, np.int64) if velocity is None else np.asarray(velocity, np.int64)
    a = np.zeros(n, np.int64) if acceleration is None else np.asarray(acceleration, np.int64)
    ref = Parker6kReferenceFilter(params, asm)
    expected = ref.run(cp, ap, v, a)
    got = parker6k_run(
        new_state(), params.to_array(), asm.to_array(), cp, ap, v, a, np.zeros(n, np.int64)
    )
    assert got.tolist() == expected, "kernel differs from reference"
    return expected


def errors(params, errs, **assumptions):
    """Commanded = error, actual = 0 (the encoder does not move)."""
    return both(params, errs, [0] * len(errs), **assumptions)


def pk(**kw) -> Parker6kParams:
    return Parker6kParams(**{**ZERO, **kw})


# --- hand-computed cases: expected numbers written from the spec, not from the code --------
# Defaults: gains in uV (q = 10 nV, FS = 1e9 q in 10 V), 12-bit DAC (N = 2048, command = 16 D),
# SSFR4 (T = 160 us).


def test_proportional_only():
    # SGP100 = 10000; E = 1000: P = 1e7 q = 0.1 V; D = floor(1e7 * 2048 / 1e9) = floor(20.48).
    p = pk(sgp=10000)
    assert errors(p, [1000, -1000, 0]) == [20 * 16, -21 * 16, 0]
    assert errors(p, [-1000], rounding="trunc") == [-20 * 16]
    # 16-bit DAC: floor(1e7 * 32768 / 1e9) = floor(327.68) = 327, command = D.
    assert errors(p, [1000], dac_bits="16") == [327]
    # mV gains: q = 10 uV, FS = 1e6: E = 10 gives 1e5 q = 1 V; floor(204.8) = 204.
    assert errors(p, [10], gain_unit="mV") == [204 * 16]


def test_manual_example_gain():
    # The spec's worked example: SGP85, E = 100: 850,000 q = 8.5 mV -> D = 1.
    assert errors(pk(sgp=8500), [100]) == [16]


def test_integral_reaches_sgilim_each_limit_mode():
    # SGI62500.00 = 6,250,000; T = 160: SGI * E * T = 1e9 * E q/1e6 = 1e3 * E q per sample.
    # E = 10000: 1e7 q = 0.1 V per sample. SGILIM .25 V = 250 mV: L = 250 * 1e5 * 1e6 = 2.5e13.
    p = pk(sgi=6_250_000, sgilim=250)
    e = [10000] * 4 + [-10000]
    # accumulator: I = 1e13, 2e13, 2.5e13 (limit), 2.5e13, 1.5e13 -> Int = I / 1e6 q;
    # D = floor(Int * 2048 / 1e9) = 20 (20.48), 40 (40.96), 51 (51.2), 51, 30 (30.72).
    assert errors(p, e) == [320, 640, 816, 816, 480]
    # output: error sum 1e4, 2e4, 3e4, 4e4, 3e4; term clamped to 2.5e13: windup keeps it.
    assert errors(p, e, integral_limit="output") == [320, 640, 816, 816, 816]
    # conditional: 3e4 would give 3e13 > L, so the sum stays at 2e4 (40); then 1e4 (20).
    assert errors(p, e, integral_limit="conditional") == [320, 640, 640, 640, 320]


def test_integral_with_zero_limit_is_off():
    assert errors(pk(sgi=6_250_000, sgilim=0), [10000, 10000]) == [0, 0]


def test_integral_timing_previous_hand_computed():
    # PK-A10 "previous": the output of sample n takes the integral term as sample n-1 left it.
    # Same numbers as above: SGI * E * T = 6,250,000 * 10000 * 160 = 1e13 q/1e6 per sample,
    # L = 250 mV * 1e5 q/mV * 1e6 = 2.5e13; D = floor(I / 1e6 * 2048 / 1e9).
    p = pk(sgi=6_250_000, sgilim=250)
    e = [10000] * 4 + [-10000, 0]
    # accumulator: I before each sample = 0, 1e13, 2e13, 2.5e13 (limit), 2.5e13, 1.5e13
    # -> D = 0, floor(20.48) = 20, floor(40.96) = 40, floor(51.2) = 51, 51, floor(30.72) = 30.
    assert errors(p, e, integral_timing="previous") == [0, 320, 640, 816, 816, 480]
    # The default ("current") reads I after the update: 1e13, 2e13, 2.5e13, 2.5e13, 1.5e13,
    # 1.5e13 -> 20, 40, 51, 51, 30, 30.
    assert errors(p, e) == [320, 640, 816, 816, 480, 480]
    # output: error sums before each sample 0, 1e4, 2e4, 3e4, 4e4, 3e4; the term
    # SGI * sum * T = 1e9 * sum, clamped to 2.5e13: 0, 1e13, 2e13, 2.5e13, 2.5e13, 2.5e13.
    assert errors(p, e, integral_limit="output", integral_timing="previous") == [
        0, 320, 640, 816, 816, 816,
    ]  # fmt: skip
    # conditional: sums before 0, 1e4, 2e4, 2e4 (3e4 refused: 3e13 > L), 2e4 (refused
    # again), 1e4 (the -1e4 sample was taken) -> 0, 20, 40, 40, 40, 20.
    assert errors(p, e, integral_limit="conditional", integral_timing="previous") == [
        0, 320, 640, 640, 640, 320,
    ]  # fmt: skip
    # With SGP: P = SGP100 (10000) * 10000 = 1e8 q = 1 V -> D = floor(204.8) = 204 at once,
    # the integral joins a sample later: 1e8 + 1e7 = 1.1e8 q -> floor(225.28) = 225.
    both_terms = pk(sgp=10000, sgi=6_250_000, sgilim=250)
    assert errors(both_terms, [10000, 10000], integral_timing="previous") == [
        204 * 16, 225 * 16,
    ]  # fmt: skip
    # trunc rounding of a negative term read before the update: I = -1e13 after the first
    # sample -> Int = -1e7 q, D = trunc(-20.48) = -20 in the second sample (floor: -21).
    assert errors(p, [-10000, 0], integral_timing="previous", rounding="trunc") == [0, -320]
    assert errors(p, [-10000, 0], integral_timing="previous") == [0, -336]


@settings(max_examples=25, deadline=None)
@given(
    sgi=st.integers(0, GAIN_MAX),
    sgilim=st.integers(0, 10_000),
    mode=st.sampled_from(ASSUMPTION_CHOICES["integral_limit"]),
    errs=st.lists(st.integers(-(2**20), 2**20), min_size=1, max_size=60),
)
def test_integral_timing_previous_is_current_one_sample_later(sgi, sgilim, mode, errs):
    # With the integral as the only term and fixed gains, "previous" is "current" delayed by
    # one sample: the integrator sees the same errors, only the read moves.
    p = pk(sgi=sgi, sgilim=sgilim)
    cur = errors(p, errs, integral_limit=mode)
    prev = errors(p, errs, integral_limit=mode, integral_timing="previous")
    assert prev == [0, *cur[:-1]]


def test_sgv_sign_convention():
    # SGV100 = 10000 uV/(count/s) * 0.01; X = 10 counts/sample at 160 us = 62,500 counts/s:
    # V = -10000 * 10 * 1e6 / 160 = -6.25e8 q = -6.25 V; D = floor(-1280.0) = -1280.
    p = pk(sgv=10000)
    # Encoder moving with the command (E = 0): velocity feedback opposes the motion.
    assert both(p, [0, 10, 20], [0, 10, 20]) == [0, -1280 * 16, -1280 * 16]
    assert both(p, [0, 10, 20], [0, 10, 20], velocity_feedback="error_rate") == [0, 0, 0]
    # Command moving, encoder still: the error grows 10 counts/sample.
    assert both(p, [0, 10, 20], [0, 0, 0]) == [0, 0, 0]
    assert both(p, [0, 10, 20], [0, 0, 0], velocity_feedback="error_rate") == [0, 20480, 20480]
    # The first sample after reset has no velocity, wherever the encoder starts.
    assert both(p, [5000, 5000], [5000, 5000]) == [0, 0]


def test_velocity_rounding_and_ssfr():
    # SSFR1: T = 330 us. SGV1.00 = 100, X = -1: V = 100 * 1 * 1e6 / 330 = 303030.30 q (+).
    # 3.0303 mV: D = floor(303030.30 * 2048 / 1e9) = floor(0.6206) = 0; X = +1 gives
    # -303030.30 -> floor -303031 q -> floor(-0.62) = -1.
    p = pk(sgv=100, ssfr=1)
    assert both(p, [0, 0, 0], [0, 1, 0]) == [0, -16, 0]
    assert both(p, [0, 0, 0], [0, 1, 0], rounding="trunc") == [0, 0, 0]


def test_feedforward_terms():
    # SGVF10.00 = 1000 per count/s; Vc = 100,000 counts/s: 1e8 q = 1 V -> floor(204.8) = 204.
    p = pk(sgvf=1000, sgaf=5000)
    assert both(p, [0], [0], velocity=[100_000]) == [204 * 16]
    # SGAF.5000 = 5000 (0.0001 steps); Ac = 1e6 counts/s^2: 5e9 / 100 = 5e7 q = 0.5 V: 102.4.
    assert both(p, [0], [0], acceleration=[1_000_000]) == [102 * 16]
    assert both(p, [0], [0], acceleration=[-1_000_000]) == [-103 * 16]
    assert both(p, [0], [0], acceleration=[-1_000_000], rounding="trunc") == [-102 * 16]
    # SGAF rounds at 1/100 q: 1 * 99 / 100 floors to 0 q, -99 to -1 q; the DAC floors
    # -1 * 2048 / 1e9 to -1 step (-16). Toward zero both stay 0.
    assert both(pk(sgaf=1), [0, 0], [0, 0], acceleration=[99, -99]) == [0, -16]
    assert both(pk(sgaf=1), [0, 0], [0, 0], acceleration=[99, -99], rounding="trunc") == [0, 0]


def test_offset_and_dac_saturation():
    # SGP120.00 = 12000: E = 1e5 gives 1.2e9 q = 12 V. SOFFS -2 V = -2000 mV = -2e8 q.
    p = pk(sgp=12000, soffs=-2000)
    # offset_then_saturate: 12 - 2 = 10 V -> D = 2048 -> clamped to 2047: 32752.
    # 0 error: -2 V -> floor(-409.6) = -410. -12 V - 2 V -> -2048: -32768.
    assert errors(p, [100_000, 0, -100_000]) == [32752, -410 * 16, -32768]
    # saturate_then_offset: sat(12 V, 10 V) - 2 V = 8 V -> floor(1638.4) = 1638;
    # sat(-12 V) - 2 V = -12 V -> -2048.
    got = errors(p, [100_000, 0, -100_000], offset_order="saturate_then_offset")
    assert got == [1638 * 16, -410 * 16, -32768]
    assert errors(p, [0], rounding="trunc") == [-409 * 16]
    # All gains 0: SOFFS alone drives the output [M].
    assert errors(pk(soffs=10_000), [12345]) == [32752]


def test_smper_trip_latches_and_outputs_zero():
    p = pk(sgp=10000, smper=100)
    # |E| = 100 does not exceed 100; 101 does: 0 from then on, latched.
    assert errors(p, [100, 101, 0, 50]) == [2 * 16, 0, 0, 0]
    assert errors(p, [100, 0], smper_compare="greater_equal") == [0, 0]
    # SMPER0: off by default (PK-A8); a limit of 0 under the alternative.
    assert errors(pk(sgp=10000, smper=0), [1000]) == [320]
    assert errors(pk(sgp=10000, smper=0), [0, 1], smper_zero="limit") == [0, 0]
    state = new_state()
    asm = Parker6kAssumptions().to_array()
    assert parker6k_step(state, p.to_array(), asm, 0, -101, 0, 0) == 0
    assert state[S_TRIPPED] == 1
    ref = Parker6kReferenceFilter(p)
    ref.step(0, -101, 0, 0)
    assert ref.tripped and ref.motion_error


def test_32_bit_wrap():
    # Commanded wrapped past 2^31 - 1 to -2^31 + 5; actual 2^31 - 5: the error is +10.
    p = pk(sgp=1_000_000)  # 10000.00 uV/count: E = 10 -> 1e7 q -> 20
    assert both(p, [-(2**31) + 5], [2**31 - 5]) == [20 * 16]
    # The encoder crossing the wrap moves +5 counts, not -2^32 + 5.
    q = pk(sgv=10000)  # X = 5: -5e6 * 1e4 / 160 = -3.125e8 q -> floor(-640.0) = -640
    assert both(q, [2**31 - 3, -(2**31) + 2], [2**31 - 3, -(2**31) + 2]) == [0, -640 * 16]


def test_gain_set_switch_at_scheduled_tick():
    # Gains in force: SGP1.00 (100); stored set 1: SGP100.00 (10000); switch at tick 3.
    # E = 1e4: 1e6 q -> floor(2.048) = 2; then 1e8 q -> floor(204.8) = 204.
    p = pk(sgp=100, sgset=[GainSet(**{**ZERO, "sgp": 10000})], sgenb=[(3, 1)])
    assert errors(p, [10_000] * 5) == [32] * 3 + [204 * 16] * 2
    assert p.gains_at(2).sgp == 100 and p.gains_at(3).sgp == 10000
    # Two switches and back to another set; the state's active set follows.
    sets = [GainSet(**{**ZERO, "sgp": s}) for s in (10000, 5000)]
    p2 = pk(sgp=100, sgset=sets, sgenb=[(1, 2), (2, 1)])
    assert errors(p2, [10_000] * 3) == [32, 102 * 16, 204 * 16]


def test_gain_switch_bumpless_only_with_accumulator():
    # SGI switches from 6250000 (1e3 q per count per sample) to 3125000 at tick 2.
    half = GainSet(**{**ZERO, "sgi": 3_125_000})
    p = pk(sgi=6_250_000, sgset=[half], sgenb=[(2, 1)])
    e = [10_000] * 3
    # accumulator: I = 1e7, 2e7, then + 0.5e7 = 2.5e7 q: D = 20, 40, 51.
    assert errors(p, e) == [320, 640, 816]
    # output: sum 1e4, 2e4, 3e4; third term with the halved SGI: 1.5e7 q -> 30.
    assert errors(p, e, integral_limit="output") == [320, 640, 480]


def test_update_keeps_state_in_kernel_and_reference():
    p1 = pk(sgi=6_250_000)
    p2 = p1.replace(sgi=3_125_000)
    asm = Parker6kAssumptions()
    ref = Parker6kReferenceFilter(p1, asm)
    state = new_state()
    out_ref, out_kernel = [], []
    for k in range(4):
        params = p1 if k < 2 else p2
        ref.update(params)
        out_ref.append(ref.step(10_000, 0, 0, 0))
        out_kernel.append(parker6k_step(state, params.to_array(), asm.to_array(), 10_000, 0, 0, 0))
    # I = 1e7, 2e7, 2.5e7, 3e7 q -> 20, 40, 51, 61.
    assert out_ref == out_kernel == [320, 640, 816, 976]


def test_enable_is_sgenb():
    p = Parker6kParams(sgset=[GainSet(sgp=1), GainSet(sgp=2, sgv=7)])
    q = p.enable(2)
    assert q.gains == GainSet(sgp=2, sgv=7) and q.sgset == p.sgset
    with pytest.raises(ParameterError, match="1 <= set <= 2"):
        p.enable(3)
    with pytest.raises(ParameterError, match="sgset is empty"):
        Parker6kParams().enable(1)


# --- kernel == reference, property tests --------------------------------------------------


def _gain(draw):
    return draw(
        st.one_of(
            st.integers(0, 20_000),
            st.sampled_from([0, GAIN_MAX]),
            st.integers(0, GAIN_MAX),
        )
    )


@st.composite
def legal_params(draw, n_ticks=500):
    model = draw(st.sampled_from(sorted(CHIP_MODELS)))
    space = parameter_space(model)
    values = {name: _gain(draw) for name in GAIN_FIELDS}
    for name in ("sgilim", "soffs", "smper"):
        spec = space[name]
        if name == "smper":
            values[name] = draw(st.one_of(st.integers(0, 10_000), st.integers(0, spec.high)))
        else:
            values[name] = draw(st.integers(spec.low, spec.high))
    values["ssfr"] = draw(st.sampled_from([1, 2, 4, 8]))
    n_sets = draw(st.integers(0, MAX_GAIN_SETS))
    sets = [GainSet(**{g: _gain(draw) for g in GAIN_FIELDS}) for _ in range(n_sets)]
    schedule = []
    if n_sets:
        ticks = sorted(draw(st.sets(st.integers(0, n_ticks + 5), max_size=8)))
        schedule = [(t, draw(st.integers(1, n_sets))) for t in ticks]
    return Parker6kParams(model=model, **values, sgset=sets, sgenb=schedule)


def inputs(seed: int, n: int):
    """Commanded/actual/velocity/acceleration: small errors, wraps, jumps and extremes."""
    rng = np.random.default_rng(seed)
    scale = int(rng.choice([10, 1000, 100_000, 2**31]))
    start = int(rng.integers(-(2**31), 2**31))
    steps = rng.integers(-scale // 10 - 1, scale // 10 + 2, n)
    cp = (start + np.cumsum(steps) + 2**31) % 2**32 - 2**31
    err = np.clip(np.cumsum(rng.integers(-scale // 10 - 1, scale // 10 + 2, n)), -scale, scale)
    ap = (cp - err + 2**31) % 2**32 - 2**31
    big = rng.random(n) < 0.05
    ap[big] = rng.integers(-(2**31), 2**31, int(big.sum()))
    v = rng.integers(-(2**40), 2**40, n) >> rng.integers(0, 40, n)
    a = rng.integers(-(2**50), 2**50, n) >> rng.integers(0, 50, n)
    v[rng.random(n) < 0.01] = np.iinfo(np.int64).max // 3
    a[rng.random(n) < 0.01] = np.iinfo(np.int64).min // 3
    return cp.astype(np.int64), ap.astype(np.int64), v, a


TICKS = 500
SETTINGS = Parker6kAssumptions.all_settings()
IDS = ["default", *[f"{k}={v}" for k, c in ASSUMPTION_CHOICES.items() for v in c[1:]]]


def test_every_assumption_setting_covers_integral_timing():
    # The kernel == reference runs (here and in test_family_contract) iterate all_settings().
    assert Parker6kAssumptions(integral_timing="previous") in SETTINGS
    assert Parker6kAssumptions().integral_timing == "current"
    codes = Parker6kAssumptions(integral_timing="previous").to_array()
    assert codes[A_INDEX["integral_timing"]] == 1 and codes.sum() == 1


@pytest.mark.parametrize("asm", SETTINGS, ids=IDS)
@settings(max_examples=20, deadline=None)
@given(params=legal_params(), seed=st.integers(0, 2**32 - 1))
def test_kernel_matches_reference_every_assumption(asm, params, seed):
    # 11 settings x 20 examples x 500 ticks = 110,000 ticks per run of the suite.
    cp, ap, v, a = inputs(seed, TICKS)
    expected = Parker6kReferenceFilter(params, asm).run(cp, ap, v, a)
    state = new_state()
    got = parker6k_run(
        state, params.to_array(), asm.to_array(), cp, ap, v, a, np.zeros(TICKS, np.int64)
    )
    np.testing.assert_array_equal(got, expected)
    bits = int(asm.dac_bits)
    assert all(-32768 <= c <= 32767 and c % 2 ** (16 - bits) == 0 for c in expected)
    assert state[4] == TICKS


@settings(max_examples=30, deadline=None)
@given(
    params=legal_params(n_ticks=200),
    seed=st.integers(0, 2**32 - 1),
    choice=st.fixed_dictionaries({k: st.sampled_from(v) for k, v in ASSUMPTION_CHOICES.items()}),
)
def test_kernel_matches_reference_mixed_assumptions(params, seed, choice):
    asm = Parker6kAssumptions(**choice)
    cp, ap, v, a = inputs(seed, 200)
    expected = Parker6kReferenceFilter(params, asm).run(cp, ap, v, a)
    got = parker6k_run(
        new_state(), params.to_array(), asm.to_array(), cp, ap, v, a, np.zeros(200, np.int64)
    )
    np.testing.assert_array_equal(got, expected)


@settings(max_examples=15, deadline=None)
@given(p1=legal_params(n_ticks=100), p2=legal_params(n_ticks=100), seed=st.integers(0, 2**32))
def test_kernel_matches_reference_across_a_params_update(p1, p2, seed):
    # A new parameter set mid-run (the runner's set_params) keeps the state in both.
    asm = Parker6kAssumptions()
    cp, ap, v, a = inputs(seed, 100)
    ref = Parker6kReferenceFilter(p1, asm)
    state = new_state()
    for k in range(100):
        if k == 50:
            ref.update(p2)
        p = p1 if k < 50 else p2
        args = (int(cp[k]), int(ap[k]), int(v[k]), int(a[k]))
        assert parker6k_step(state, p.to_array(), asm.to_array(), *args) == ref.step(*args)


# --- legal ranges ------------------------------------------------------------------------


def illegal_cases():
    for model in sorted(CHIP_MODELS):
        for name, spec in parameter_space(model).items():
            for value in (spec.low - 1, spec.high + 1, 1.5, True, "7"):
                yield pytest.param(model, name, spec, value, id=f"{model}-{name}-{value!r}")


@pytest.mark.parametrize("model,name,spec,value", list(illegal_cases()))
def test_every_illegal_value_is_rejected_with_its_range(model, name, spec, value):
    with pytest.raises(ParameterError, match=f"{spec.low} <= {name} <= {spec.high}") as info:
        Parker6kParams(model=model, **{name: value})
    assert repr(value) in str(info.value) or str(value) in str(info.value)


@pytest.mark.parametrize("ssfr", [3, 5, 6, 7])
def test_ssfr_between_legal_values_is_rejected(ssfr):
    with pytest.raises(ParameterError, match=f"ssfr must be one of 1, 2, 4, 8.*got ssfr={ssfr}"):
        Parker6kParams(ssfr=ssfr)


@pytest.mark.parametrize("gain", GAIN_FIELDS)
@pytest.mark.parametrize("value", [-1, GAIN_MAX + 1, 2.5])
def test_stored_set_values_are_rejected_naming_the_set(gain, value):
    sets = [GainSet(), {**GainSet().to_dict(), gain: value}]
    with pytest.raises(
        ParameterError, match=rf"0 <= {gain} <= {GAIN_MAX}.*stored gain set 2 \(SGSET2\)"
    ):
        Parker6kParams(sgset=sets)
    tampered = GainSet()
    object.__setattr__(tampered, gain, value)
    with pytest.raises(ParameterError, match=r"stored gain set 1 \(SGSET1\)"):
        Parker6kParams(sgset=[tampered])


@pytest.mark.parametrize(
    ("sgset", "sgenb", "match"),
    [
        ([GainSet()] * 6, (), "at most 5 stored gain sets"),
        ("abc", (), "sgset must be a sequence"),
        ([{"sgp": 1}], (), "missing sgi, sgv, sgvf, sgaf"),
        ([{**GainSet().to_dict(), "sgq": 1}], (), "unknown name 'sgq'"),
        ([7], (), r"sgset\[0\] must be a GainSet"),
        ((), [(0, 1)], "sgset is empty"),
        ([GainSet()], [(0, 2)], "1 <= set <= 1"),
        ([GainSet()], [(0, 0)], "1 <= set <= 1"),
        ([GainSet()], [(-1, 1)], "0 <= tick <= 2147483647"),
        ([GainSet()], [(2**31, 1)], "0 <= tick <= 2147483647"),
        ([GainSet()], [(5, 1), (5, 1)], "strictly increase"),
        ([GainSet()], [(5, 1, 1)], r"sgenb\[0\] must be a \(tick, set\) pair"),
        ([GainSet()], [(0.5, 1)], "tick must be an integer"),
        ([GainSet()], 5, "sgenb must be a sequence"),
    ],
)
def test_illegal_gain_sets_and_schedules(sgset, sgenb, match):
    with pytest.raises(ParameterError, match=match):
        Parker6kParams(sgset=sgset, sgenb=sgenb)


def test_range_edges_are_legal():
    for model in CHIP_MODELS:
        space = parameter_space(model)
        Parker6kParams(model=model, **{n: s.low for n, s in space.items()})
        Parker6kParams(model=model, **{n: s.high for n, s in space.items()})


def test_unknown_names_suggest_close_ones():
    with pytest.raises(ParameterError, match="Did you mean sgp"):
        Parker6kParams.from_dict({"model": "6250", "sgpp": 1})
    with pytest.raises(ParameterError, match="Did you mean 6K"):
        Parker6kParams(model="6k2")
    with pytest.raises(ParameterError, match="PK-A6 rounding must be one of 'floor', 'trunc'"):
        Parker6kAssumptions(rounding="nearest")


def test_sample_time_and_array_layout():
    periods = {1: 330e-6, 2: 185e-6, 4: 160e-6, 8: 150e-6}
    for ssfr, t in periods.items():
        p = Parker6kParams(ssfr=ssfr)
        assert p.sample_time_s == t  # the correctly rounded double of the exact period
    p = Parker6kParams(model="6K", sgp=7, sgset=[GainSet(sgaf=9)], sgenb=[(4, 1), (9, 1)])
    arr = p.to_array()
    assert arr.dtype == np.int64 and arr[0] == 160 and arr[5] == 7 and arr[14] == 9
    assert arr[35:].tolist() == [1, 2, 4, 9, 1, 1]
    assert p.motor_limit == 32752 and p.model == "6K"
    assert Parker6kParams.from_dict(p.to_dict()) == p
