"""PMD paths the defaults switch off, hand-computed from docs/chips/pmd.md (section 3).

A misreading copied into both the kernel and the reference passes the kernel == reference
tests; these cases pin the numbers on the paths that are off by default: biquad feedback
(a1, a2), error saturation (PMD-A6 ``sat16``) feeding the integral, and the comparisons at
their exact boundaries.
"""

from __future__ import annotations

import pytest

from servogym.chips.pmd._reference import PMDReferenceFilter
from tests.chips.test_pmd_filter import both, pmd

MAGELLAN = dict(model="MC58000", biquad1_enable=1)


def test_biquad_feedback_a1_a2():
    # kp 40, E = 100: stage input x = 4000 every cycle; kout 16384: Y = U / 4 (floor).
    # Q14 (PMD-A12): b0 = 16384 (1.0), a1 = -8192 (-0.5), a2 = 4096 (0.25), k = 1.0:
    #   acc = 16384 x - a1 y1 - a2 y2 = 65,536,000 + 8192 y1 - 4096 y2; w = acc >> 14.
    #   n=0: y1 = y2 = 0: w = 4000                                  -> Y = 1000
    #   n=1: y1 = 4000: 65,536,000 + 32,768,000 = 98,304,000: 6000   -> Y = 1500
    #   n=2: y1 = 6000, y2 = 4000: + 49,152,000 - 16,384,000: 6000   -> Y = 1500
    #   n=3: y1 = y2 = 6000: 65,536,000 + 49,152,000 - 24,576,000 = 90,112,000: 5500 -> 1375
    #   n=4: y1 = 5500, y2 = 6000: + 45,056,000 - 24,576,000 = 86,016,000: 5250
    #        -> Y = 5250 / 4 = 1312.5: floor 1312 (trunc alike, positive).
    coeffs = dict(b0=16384, a1=-8192, a2=4096, k=16384)
    p = pmd(kp=40, **MAGELLAN, **{f"biquad1_{n}": v for n, v in coeffs.items()})
    assert both(p, [100] * 5) == [1000, 1500, 1500, 1375, 1312]
    # The mirror image: w = -5250 exactly, Y = -1312.5: floor -1313, trunc -1312.
    assert both(p, [-100] * 5) == [-1000, -1500, -1500, -1375, -1313]
    assert both(p, [-100] * 5, rounding="trunc")[-1] == -1312
    # Stage 2 alone (stage 1 bypassed) reads its own coefficients and state words.
    p2 = pmd(
        kp=40, model="MC58000", biquad2_enable=1,
        **{f"biquad2_{n}": v for n, v in coeffs.items()},
    )  # fmt: skip
    assert both(p2, [100] * 5) == [1000, 1500, 1500, 1375, 1312]


@pytest.mark.parametrize("stage", [1, 2])
@pytest.mark.parametrize(
    "coeff,expected",
    [
        # kp 1, E = 4003: x = 4003 every cycle; Y = w / 4 (floor), so one count of stale
        # state (4004) would show as 1001. Each coefficient 1.0 (Q14 16384) adds one word:
        ("b1", [1000, 2001, 2001]),  # w = x + x1: 4003, 8006, 8006
        ("b2", [1000, 1000, 2001]),  # w = x + x2: 4003, 4003, 8006
        ("a1", [1000, 2001, 3002]),  # a1 = -1.0, w = x + y1: 4003, 8006, 12009
        ("a2", [1000, 1000, 2001]),  # a2 = -1.0, w = x + y2: 4003, 4003, 8006
    ],
)
def test_each_biquad_state_word_starts_at_zero(stage, coeff, expected):
    value = 16384 if coeff.startswith("b") else -16384
    p = pmd(kp=1, model="MC58000", **{f"biquad{stage}_enable": 1, f"biquad{stage}_{coeff}": value})
    assert both(p, [4003] * 3) == expected


def test_reference_counts_cycles():
    # n counts servo cycles from reset (spec 3, step 11); reset and update keep to that.
    ref = PMDReferenceFilter(pmd(kp=1))
    for _ in range(7):
        ref.step(0, 0, 0, 0)
    assert ref.cycle == 7
    ref.update(pmd(kp=2))
    assert ref.cycle == 7
    ref.reset()
    assert ref.cycle == 0 and ref.integral == 0 and ref.biquad_state == [[0] * 4, [0] * 4]


def test_biquad_feedback_q15():
    # The same words read as Q1.15 (PMD-A12 q15): b0 = k = 0.5, a1 = -0.25, a2 = 0.125.
    #   n=0: acc = 65,536,000 >> 15 = 2000; out = 16384 * 2000 >> 15 = 1000   -> Y = 250
    #   n=1: + 8192 * 2000 = 81,920,000 >> 15 = 2500; out 1250                -> Y = 312
    #   n=2: 65,536,000 + 8192 * 2500 - 4096 * 2000 = 77,824,000 >> 15 = 2375;
    #        out = 16384 * 2375 >> 15 = 1187 (1187.5 floored); Y = 1187 / 4    -> 296
    p = pmd(kp=40, **MAGELLAN, biquad1_a1=-8192, biquad1_a2=4096, biquad1_k=16384)
    assert both(p, [100] * 3, biquad_format="q15") == [250, 312, 296]


def test_biquads_in_series():
    # Stage 1: b1 = 1.0 adds the previous input (w = x + x1); stage 2: a1 = -0.5 feeds back
    # half its previous output (w = x + w1 / 2). x = 4000: stage 1 gives 4000, 8000, 8000;
    # stage 2: 4000, 8000 + 2000 = 10000, 8000 + 5000 = 13000; Y = U / 4: 1000, 2500, 3250.
    p = pmd(kp=40, model="MC58000", biquad1_enable=1, biquad2_enable=1,
            biquad1_b1=16384, biquad2_a1=-8192)  # fmt: skip
    assert both(p, [100] * 3) == [1000, 2500, 3250]


def test_biquad_words_saturate_to_32_bits():
    # sat48 accumulator: U = 32767 * 100000 = 3,276,700,000 > 2^31 - 1. The stage input is
    # sat32(U) = 2,147,483,647; b0 = 1.0: w = 2,147,483,647; k = 0.5: out = 1,073,741,823
    # (2,147,483,647 * 8192 >> 14 floors the half). kout = 1: Y = out >> 16 = 16383.
    p = pmd(kp=32767, kout=1, **MAGELLAN, biquad1_k=8192)
    assert both(p, [100_000], accumulator="sat48") == [16383]
    # a1 = -1.0: on the second cycle w = x + y1 = 2 (2^31 - 1) saturates to 2^31 - 1, so the
    # output is 1,073,741,823 -> 16383 again (unsaturated it would double: Y = 32767).
    p = pmd(kp=32767, kout=1, **MAGELLAN, biquad1_k=8192, biquad1_a1=-16384)
    assert both(p, [100_000] * 2, accumulator="sat48") == [16383, 16383]


def test_error_saturation_feeds_the_integral():
    # PMD-A6 sat16: E = sat16(40000) = 32767 enters the integral; ki = 256 makes the term I;
    # kout 16384: Y = I / 4. I = 32767 -> 8191 (8191.75 floored), I = 65534 -> 16383.
    p = pmd(ki=256, integration_limit=100_000)
    assert both(p, [40_000, 40_000], error_saturation="sat16") == [8191, 16383]
    # Without it (the default) the 32-bit error enters: I = 40000, 80000 -> 10000, 20000.
    assert both(p, [40_000, 40_000]) == [10000, 20000]
    # Negative side: sat16(-40000) = -32768; I = -32768, -65536 -> -8192, -16384.
    assert both(p, [-40_000, -40_000], error_saturation="sat16") == [-8192, -16384]
    # The saturated error feeds the derivative too (kd 4: Y = D): E = 40000, 40001 read as
    # 32767, 32767: D = 32767, 0. Unsaturated: D = sat16(40000) = 32767, then 1.
    assert both(pmd(kd=4), [40_000, 40_001], error_saturation="sat16") == [32767, 0]
    assert both(pmd(kd=4), [40_000, 40_001]) == [32767, 1]


def test_integration_limit_at_equality():
    # Limit 200: I = 100, 200 (equal: kept), 200 (clamped). Y = I / 4 with ki 256.
    p = pmd(ki=256, integration_limit=200)
    assert both(p, [100, 100, 100]) == [25, 50, 50]
    assert both(p, [-100, -100, -100]) == [-25, -50, -50]


def test_motor_limit_and_bias_at_their_edges():
    # kp 4: Y = E. motor_limit 1000: Y = 1000 passes, 1001 is limited; -1000 / -1001 alike.
    p = pmd(kp=4, motor_limit=1000)
    assert both(p, [1000, 1001, -1000, -1001]) == [1000, 1000, -1000, -1000]
    # PMD-A5 limit_then_bias: sat16(clamp(Y, -32767, 32767) + bias): -32767 - 2 = -32769
    # saturates to -32768; bias_then_limit: clamp(-40000 - 2) = -32767.
    p = pmd(kp=4, bias=-2, motor_limit=32767)
    assert both(p, [-40_000], bias_order="limit_then_bias") == [-32768]
    assert both(p, [-40_000]) == [-32767]


def test_motion_error_compare_on_the_negative_side():
    # |E| = 100 does not exceed 100 (PMD-A11 greater); -101 does; greater_equal trips at -100.
    p = pmd(kp=40, position_error_limit=100)
    assert both(p, [-100, -101, 0]) == [-1000, 0, 0]
    assert both(p, [-100, 0], error_limit_compare="greater_equal") == [0, 0]


def test_smallest_negative_values_round_by_pmd_a1():
    # kp 1, kout 1: Y = shr(E, 16). E = -1: floor -1, trunc 0; E = -65536: -1 both;
    # E = -65537: floor -2, trunc -1.
    p = pmd(kp=1, kout=1)
    assert both(p, [-1, -65536, -65537]) == [-1, -1, -2]
    assert both(p, [-1, -65536, -65537], rounding="trunc") == [0, -1, -1]


def test_feedforward_fraction_rounding_negative():
    # PMD-A3 fraction: shr(kvff * V, 16). kvff 1, V = -1 (16.16): -1 / 65536: floor -1,
    # trunc 0. MC58000 with kout 65535: Y = shr(FF * 65535, 16): -1 -> -1 (floor), 0 -> 0.
    p = pmd(kvff=1, model="MC58000", kout=65535)
    assert both(p, [0], velocity=-1, feedforward_input="fraction") == [-1]
    assert both(p, [0], velocity=-1, feedforward_input="fraction", rounding="trunc") == [0]
    # PMD-A4 no: FF is added after Kout, so the shift's own rounding of -1 shows: -1 or 0.
    frac_after = dict(feedforward_input="fraction", kout_scales_feedforward="no")
    assert both(p, [0], velocity=-1, **frac_after) == [-1]
    assert both(p, [0], velocity=-1, rounding="trunc", **frac_after) == [0]
    # Acceleration the same way: kaff 3, A = -65537 (-1.0000153): -196611 / 65536 = -3.00002:
    # floor -4, trunc -3; Y: -4 * 65535 >> 16 = -4 (floor of -3.99994), trunc -2.99995 -> -2.
    p = pmd(kaff=3, model="MC58000", kout=65535)
    assert both(p, [0], acceleration=-65537, feedforward_input="fraction") == [-4]
    got = both(p, [0], acceleration=-65537, feedforward_input="fraction", rounding="trunc")
    assert got == [-2]
