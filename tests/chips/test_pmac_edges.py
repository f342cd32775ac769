"""Turbo PMAC boundaries and the kernel's exactness shortcut, hand-computed from
docs/chips/pmac.md (section 3).

Kernel == reference tests with random registers seldom land on a comparison's exact edge or
on the bound where the kernel clamps Y before the Ixx30 product; these cases do, with the
expected numbers worked out from the spec.
"""

from __future__ import annotations

import pytest

from servogym.chips.pmac import PMACParams
from tests.chips.test_pmac_filter import UNIT, both, pmac

# Ixx08 = 256 and Ixx30 = 2^16 make O = 256 FEd and the DAC value X = O >> 8 = FEd exactly
# (FEd in 1/32 count), so the output shows the deadband stage's result itself.
SHOW_FED = dict(position_loop_scale=256, proportional_gain=2**16)


def test_deadband_edge_on_the_negative_side():
    # Ixx65 = 1 (B = 2 in 1/32 count), Ixx64 = 1. FE = 32 (C - A) + f.
    #   FE = -1 (C = -1, f = 31): inside, FEd = shr(-1 * 17, 4) = floor(-1.0625) = -2.
    #   FE = -2 = -B (f = 30): |FE| < B is false: outside, FEd = FE - shr(1 * 2, 4) = -2;
    #     the inside formula would give floor(-34 / 16) = -3.
    #   FE = -3 (f = 29): outside, -3 - 0 = -3.
    p = pmac(**SHOW_FED, deadband_size=1, deadband_gain=1)
    assert both(p, [-1], fraction=[31]) == [-2]
    assert both(p, [-1], fraction=[30]) == [-2]
    assert both(p, [-1], fraction=[29]) == [-3]
    # FE = +B: both formulas give 2 (the offset form is continuous at the edge).
    assert both(p, [0], fraction=[2]) == [2]
    # Ixx65 = 3 (B = 6), Ixx64 = 5: offset shr(5 * 6, 4) = 1. FE = -6: outside, -6 - 1 = -7
    # (inside would be floor(-6 * 21 / 16) = floor(-7.875) = -8); FE = -5 (f = 27): inside,
    # floor(-5 * 21 / 16) = floor(-6.5625) = -7; FE = +6: 6 + 1 = 7.
    p = pmac(**SHOW_FED, deadband_size=3, deadband_gain=5)
    assert both(p, [-1], fraction=[26]) == [-7]
    assert both(p, [-1], fraction=[27]) == [-7]
    assert both(p, [0], fraction=[6]) == [7]
    # PMAC-A7 plain: outside the band the error passes unchanged: -6.
    assert both(p, [-1], fraction=[26], deadband_outside="plain") == [-6]


def test_fatal_following_error_on_the_negative_side():
    # Ixx11 = 160 (320 in 1/32 count): FE = -320 does not exceed it; -321 (C = -11, f = 31:
    # -352 + 31) does, and the motor is killed from then on.
    p = pmac(fatal_following_error_limit=160)
    assert both(p, [-10, -11, 0], fraction=[0, 31, 0]) == [-320, 0, 0]
    assert both(p, [-10, 0], trip_compare="greater_equal") == [0, 0]


def big(**kw) -> PMACParams:
    """Ixx08 = 2^22, every other term off: Y = 2^22 * 32 * E = 2^27 E (E in counts)."""
    return PMACParams(**{**UNIT, "position_loop_scale": 2**22, **kw})


def test_ixx30_product_near_the_clamp_bound():
    # Ixx30 = 1: O = shr(Y, 16), X = O >> 8 = floor(Y / 2^24) = 8 E while |O| < 2^23.
    #   E = 2048: Y = 2^38 -> 16384. E = 3072: Y = 3 * 2^37 (between 2^38 and 2^39) -> 24576.
    #   E = 4095: Y = 2^39 - 2^27 -> 32760.
    #   E = 4096: Y = 2^39 -> O = 2^23 saturates to 2^23 - 1 -> 32767.
    #   E = -4096: O = -2^23 (legal) -> X = -32768 -> output limit -32767.
    p = big(proportional_gain=1)
    assert both(p, [2048]) == [16384]
    assert both(p, [3072]) == [24576]
    assert both(p, [4095]) == [32760]
    assert both(p, [4096]) == [32767]
    assert both(p, [-3072]) == [-24576]
    assert both(p, [-4096]) == [-32767]
    # Ixx30 = -1 inverts: E = 3072 -> O = -3 * 2^21 -> -24576; E = -4095 -> 32760.
    p = big(proportional_gain=-1)
    assert both(p, [3072]) == [-24576]
    assert both(p, [-4095]) == [32760]
    # Ixx30 = 2 doubles: E = 2047 -> 2 * 2^27 * 2047 / 2^24 = 32752; E = 2048 -> 2^23
    # saturates -> 32767.
    p = big(proportional_gain=2)
    assert both(p, [2047]) == [32752]
    assert both(p, [2048]) == [32767]
    # PMAC-A5 before_kp: the notch sees sat32(Y) = 2^31 - 1 for Y = 3 * 2^37, then
    # O = (2^31 - 1) >> 16 = 32767 and X = 32767 >> 8 = 127.
    assert both(big(proportional_gain=1), [3072], notch_position="before_kp") == [127]


def test_ixx30_product_beyond_int64():
    # Largest Ixx08 and big-step window: FE enters as 2 Ixx67 = 16,777,214; Y = 8,388,607 *
    # 16,777,214 = 140,737,454,800,898 (just inside 48 bits). Ixx30 Y is about 1.2e21, past
    # int64; the output word saturates: +32767, and -32768 limited to -32767.
    p = PMACParams(**{**UNIT, "position_loop_scale": 8388607, "big_step_limit": 8388607})
    assert both(p.replace(proportional_gain=8388607), [10**6]) == [32767]
    assert both(p.replace(proportional_gain=-8388608), [10**6]) == [-32767]
    assert both(p.replace(proportional_gain=-8388608), [-(10**6)]) == [32767]
    assert both(p.replace(proportional_gain=1), [-(10**6)]) == [-32767]


def test_deadband_of_zero_width_and_the_smallest_negative_inside():
    # Ixx65 = 0: no error is inside (|FE| < 0 never holds); with the offset form the offset
    # is shr(Ixx64 * 0, 4) = 0, so FEd = FE: -1 and 1 pass unchanged even with Ixx64 = 16.
    p = pmac(**SHOW_FED, deadband_size=0, deadband_gain=16)
    assert both(p, [-1], fraction=[31]) == [-1]
    assert both(p, [0], fraction=[1]) == [1]
    # Ixx65 = 1, Ixx64 = -15: inside, FEd = shr(-1 * 1, 4): floor -1, trunc 0 (PMAC-A1).
    p = pmac(**SHOW_FED, deadband_size=1, deadband_gain=-15)
    assert both(p, [-1], fraction=[31]) == [-1]
    assert both(p, [-1], fraction=[31], rounding="trunc") == [0]


def test_every_trip_sets_the_tripped_word_to_one():
    from servogym.chips.pmac import PMACAssumptions
    from servogym.chips.pmac._kernel import S_TRIPPED, new_state, pmac_step

    # Ixx11 = 160 under PMAC-A12 greater_equal: FE = 320 trips; Ixx63 = -1: |IS| >= 2^24
    # after one integration of 2^20 * 32 * 16 (Ixx33 = 2^20, FE = 16 counts) trips next.
    cases = [
        (pmac(fatal_following_error_limit=160), dict(trip_compare="greater_equal"), [10]),
        (pmac(integral_gain=2**20, integration_limit=-1), {}, [16, 16]),
    ]
    for params, asm, errors in cases:
        state = new_state()
        for e in errors:
            pmac_step(state, params.to_array(), PMACAssumptions(**asm).to_array(), e, 0, 0, 0)
        assert state[S_TRIPPED] == 1


def test_controller_response_by_hand():
    # docs/chips/pmac.md, section 6 (controller_response): with Ixx33 = 0, the notch off,
    # C(z) = 2^-19 Ixx30 [Ixx08 + Ixx31 Ixx09 2^-7 (1 - z^-1)]. Defaults: Ixx30 2000,
    # Ixx08 = Ixx09 = 96, Ixx31 1280, so Ixx31 Ixx09 / 128 = 960 and g = 2000 / 2^19.
    #   Nyquist, z^-1 = -1: C = g (96 + 960 * 2) = 2000 * 2016 / 524288 = 7.6904296875.
    #   fs / 4, z^-1 = -j: C = g (96 + 960 (1 + j)) = g (1056 + 960 j).
    from servogym.chips.pmac import controller_response

    p = PMACParams(integral_gain=0)
    fs = 1.0 / p.sample_time_s
    r = controller_response(p, [fs / 2, fs / 4])
    g = 2000 / 2**19
    assert r.response[0] == pytest.approx(7.6904296875, abs=1e-9)
    assert r.response[1] == pytest.approx(g * (1056 + 960j), abs=1e-9)


def test_notch_forms_on_negative_words():
    # FE = -1 count: O = -8192 every update; n1 = 1.0: w = x + x1 -> -8192, -16384, -16384,
    # DAC -32, -64, -64, in both forms and both positions (the words are exact multiples of
    # 2^22 / 2^22, so no rounding enters).
    p = pmac(notch_n1=2**22)
    for form in ("df1", "df2"):
        for position in ("after_kp", "before_kp"):
            got = both(p, [-1] * 3, notch_form=form, notch_position=position)
            assert got == [-32, -64, -64], (form, position)
