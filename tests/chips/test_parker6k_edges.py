"""Parker 6000 boundaries and the kernel's exactness shortcuts, hand-computed from
docs/chips/parker6k.md (section 4).

Kernel == reference tests with random settings seldom land on the conditional integral
limit's equality or on the bounds where the kernel clamps an input before a product
(``xc``, ``vc``, ``ac`` in ``_kernel.py``); these cases do.
"""

from __future__ import annotations

import pytest

from tests.chips.test_parker6k_filter import both, errors, pk

W = 2**47  # every term's saturation, in q (spec 4.0)


def test_conditional_integral_limit_at_equality():
    # SGI = 6,250,000, T = 160 us (SSFR4): SGI * T = 1e9, so the term is 1e9 * I q/1e6.
    # SGILIM 2.5 V = 2500 mV: L = 2500 * 1e5 * 1e6 = 2.5e14. PK-A4 conditional:
    #   E = 125000: c = 125000, |1e9 c| = 1.25e14 <= L: I = c; Int = 1.25e8 q = 1.25 V;
    #     D = floor(1.25e8 * 2048 / 1e9) = 256 -> command 16 D = 4096.
    #   c = 250000: |1e9 c| = 2.5e14 = L: kept (<=): Int = 2.5e8, D = 512 -> 8192.
    #   c = 375000: over L: I stays 250000 -> 8192.
    #   E = -1: c = 249999: kept; Int = 249,999,000; D = floor(511.997952) = 511 -> 8176.
    p = pk(sgi=6_250_000, sgilim=2500)
    errs = [125_000, 125_000, 125_000, -1]
    assert errors(p, errs, integral_limit="conditional") == [4096, 8192, 8192, 8176]
    # PK-A4 output: I = 375000, then 374999; the term stays at L until I falls below it.
    assert errors(p, errs, integral_limit="output") == [4096, 8192, 8192, 8192]
    # Negative side: c = -250000 is kept; then -249999: Int = -249,999,000,
    # D = floor(-511.997952) = -512 -> -8192 (trunc: -511 -> -8176).
    neg = [-e for e in errs]
    assert errors(p, neg, integral_limit="conditional") == [-4096, -8192, -8192, -8192]
    got = errors(p, neg, integral_limit="conditional", rounding="trunc")
    assert got == [-4096, -8192, -8192, -8176]


def test_accumulator_integral_limit_at_equality():
    # PK-A4 accumulator: I = sat(I + SGI E T, L) with SGI T = 1e9: 1.25e14, 2.5e14 (= L,
    # kept), L, then L - 1e9 = 2.49999e14: Int = 249,999,000 -> 8176, as above.
    p = pk(sgi=6_250_000, sgilim=2500)
    assert errors(p, [125_000, 125_000, 125_000, -1]) == [4096, 8192, 8192, 8176]


# The shortcuts are visible only where another term cancels the saturated one: gains in mV
# (PK-A1: FS = 1e6 q in 10 V) and a 16-bit DAC (PK-A2: D = floor(Y * 32768 / 1e6), command
# D) make one q about 1/30 of a DAC step. SGP = 9,999,975 and E = 14,073,784 give
# P = 140,737,488,155,400 = W - 199,928 (P itself is not saturated).
FINE = dict(gain_unit="mV", dac_bits="16")
SGP, E_NEAR_W, R = 9_999_975, 14_073_784, 199_928


def test_velocity_term_at_the_kernel_clamp_bound():
    # SSFR8: T = 150 us. The kernel clamps y = SGV X to xc = W T // 1e6 + 1 = 21,110,623,254
    # = 7,428,087 * 2842. With SGV = 7,428,087 and the encoder moving X = 2842 counts in
    # sample 1, |y| = xc exactly: V = -xc * 1e6 / 150 = -(W + 4672) saturates to -W.
    # Sample 1: E = 14,073,784: U = (W - 199,928) - W = -199,928;
    # D = floor(-199,928 * 32768 / 1e6) = floor(-6551.24) = -6552.
    # (A bound one lower would give V = floor(-(xc - 1) 1e6 / 150) = -W + 1994 and -6486.)
    p = pk(sgp=SGP, sgv=7_428_087, ssfr=8)
    commanded = [0, 2842 + E_NEAR_W]
    assert both(p, commanded, [0, 2842], **FINE) == [0, -6552]
    # One count less of travel: |y| = xc - SGV = 21,103,195,167, V = -(y * 1e6 / 150)
    # = -140,687,967,780,000 (exact) = -(W - 49,520,575,328), not saturated:
    # U = W - R - 140,687,967,780,000 = 49,520,375,400 q, over 10 V: D = 32767.
    assert both(p, [0, 2841 + E_NEAR_W], [0, 2841], **FINE) == [0, 32767]


def test_feedforward_terms_at_the_kernel_clamp_bounds():
    # SGVF = 9,999,999: the kernel clamps Vc to vc = W // SGVF + 1 = 14,073,751, where
    # SGVF * vc = W + 7,570,921 saturates to W. With E = -14,073,784: P = -(W - R), and
    # U = W - (W - R) = 199,928: D = floor(199,928 * 32768 / 1e6) = floor(6551.24) = 6551.
    # (A bound one lower: VF = SGVF * 14,073,750 = W - 2,429,078 and the DAC saturates low.)
    p = pk(sgp=SGP, sgvf=9_999_999)
    assert both(p, [-E_NEAR_W], [0], velocity=[14_073_751], **FINE) == [6551]
    assert both(p, [-E_NEAR_W], [0], velocity=[10**12], **FINE) == [6551]
    assert both(p, [-E_NEAR_W], [0], velocity=[14_073_750], **FINE) == [-32768]
    # SGAF = 9,999,999: ac = 100 W // SGAF + 1 = 1,407,375,025, where
    # SGAF * ac / 100 = W + 70,921.75 saturates to W: D = 6551 again. With Ac = ac - 1:
    # AF = floor(9,999,999 * 1,407,375,024 / 100) = W - 29,079 (not saturated), so
    # U = 199,928 - 29,079 = 170,849: D = floor(5598.38) = 5598.
    p = pk(sgp=SGP, sgaf=9_999_999)
    assert both(p, [-E_NEAR_W], [0], acceleration=[1_407_375_025], **FINE) == [6551]
    assert both(p, [-E_NEAR_W], [0], acceleration=[1_407_375_024], **FINE) == [5598]


def test_reference_state_after_reset():
    # Reset (spec 4, state): every word zero, the gains in force are set 0 (the reset ones).
    from servogym.chips.parker6k import Parker6kReferenceFilter

    ref = Parker6kReferenceFilter(pk(sgp=1))
    assert (ref.active_set, ref.integral, ref.cycle, ref.tripped) == (0, 0, 0, False)
    assert (ref.previous_actual, ref.previous_error) == (0, 0)


def test_output_integral_error_sum_saturates_at_32_bits():
    # PK-A4 output: I = clamp(I + E, -2^31, 2^31 - 1); Int = div(sat(SGI I T, L), 1e6).
    # mV gains and a 16-bit DAC (D = floor(Y * 32768 / 1e6), command D). SGI = 6,250,000 and
    # T = 160: SGI T = 1e9, Int = 1000 I q until L; SGILIM 1 V: L = 1000 * 100 * 1e6 = 1e11.
    #   E = 2^31 - 1: I = 2^31 - 1 (at the bound); Int = L / 1e6 = 1e5 q -> D = 3276 (.8).
    #   E = 2^31 - 1 again: I stays 2^31 - 1 -> 3276.
    #   E = -(2^31 - 1): I = 0 -> 0 (one count off, I = +-1, would show as +-1000 q: +-33).
    #   E = 1: I = 1: 1000 q -> D = floor(32.768) = 32.
    p = pk(sgi=6_250_000, sgilim=1000)
    top = 2**31 - 1
    errs = [top, top, -top, 1]
    assert errors(p, errs, integral_limit="output", **FINE) == [3276, 3276, 0, 32]
    # The negative end: -2^31 twice (I = -2^31, kept), then 2^31 - 1: I = -1 -> -1000 q,
    # D = floor(-32.768) = -33; then 1: I = 0. Int = -L: floor(-3276.8) = -3277.
    errs = [-(2**31), -(2**31), top, 1]
    assert errors(p, errs, integral_limit="output", **FINE) == [-3277, -3277, -33, 0]


def test_smallest_negative_quotient_rounds_by_pk_a6():
    # SGAF = 1 (.01), Ac = -1: AF = div(-1, 100): floor -1, trunc 0. SGP = 1, E = -15624:
    # P = -15624 q. mV, 16-bit: D = div(U * 32768, 1e6), where U = -15625 is exactly -512.
    #   floor: U = -15625 -> D = -512.   trunc: U = -15624 -> -511.97 -> -511.
    p = pk(sgp=1, sgaf=1)
    assert both(p, [-15624], [0], acceleration=[-1], **FINE) == [-512]
    assert both(p, [-15624], [0], acceleration=[-1], rounding="trunc", **FINE) == [-511]


def test_smper_trip_on_an_error_of_minus_one():
    # SGP 100 (10000): E = -1 gives P = -10000 q, D = floor(-0.02048) = -1, command -16.
    # PK-A8 limit with SMPER0: any |E| > 0 trips; PK-A7 greater_equal with SMPER1: |E| >= 1.
    p = pk(sgp=10000)
    assert errors(p, [0, -1, 0]) == [0, -16, 0]  # SMPER0 off (default): no trip
    assert errors(p, [0, -1, 0], smper_zero="limit") == [0, 0, 0]
    assert errors(p.replace(smper=1), [0, -1, 0], smper_compare="greater_equal") == [0, 0, 0]
    assert errors(p.replace(smper=1), [0, -1, 0]) == [0, -16, 0]


def test_gain_sets_are_frozen():
    import dataclasses

    from servogym.chips.parker6k import GainSet

    g = GainSet(sgp=1, sgi=0, sgv=0, sgvf=0, sgaf=0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        g.sgp = 2


def test_reference_run_refuses_sequences_of_unequal_length():
    from servogym.chips.parker6k import Parker6kReferenceFilter

    with pytest.raises(ValueError, match="zip"):
        Parker6kReferenceFilter(pk()).run([0, 0], [0], [0, 0], [0, 0])
