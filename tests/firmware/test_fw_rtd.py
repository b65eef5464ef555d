"""Integer Pt100 conversion against IEC 60751 reference points and the exact inverse."""

import pytest
from hypothesis import given, settings, strategies as st

from firmware import rtd

A, B, C = 3.9083e-3, -5.775e-7, -4.183e-12


def ratio(t):
    r = 1 + A * t + B * t * t
    if t < 0:
        r += C * (t - 100) * t ** 3
    return r


def exact_inverse(q):
    """Temperature (degC) whose R/R0 is q, by Newton on the full relation (float64)."""
    t = (q - 1) / A
    for _ in range(60):
        f = ratio(t) - q
        d = A + 2 * B * t + (C * (4 * t ** 3 - 300 * t * t) if t < 0 else 0)
        step = f / d
        t -= step
        if abs(step) < 1e-12:
            break
    return t


@pytest.mark.parametrize("t_c, ohm", [(-50, 80.31), (0, 100.00), (20, 107.79), (50, 119.40),
                                      (100, 138.51), (200, 175.86)])
def test_reference_points(t_c, ohm):
    # the table values are rounded to 0.01 ohm, i.e. +-0.013 degC
    got = rtd.temperature_mC(round(ohm * 1e5))
    assert abs(got - t_c * 1000) <= 14
    # and exactly at the relation's resistance the conversion is within 0.002 degC
    assert abs(rtd.temperature_mC(round(ratio(t_c) * 1e7)) - t_c * 1000) <= 2


@settings(max_examples=2000, deadline=None)
@given(st.integers(min_value=round(ratio(-50) * 1e7), max_value=round(ratio(200) * 1e7)))
def test_within_2_millikelvin_of_exact_inverse(r):
    t = exact_inverse(r / 1e7) * 1000
    assert abs(rtd.temperature_mC(r) - t) <= 2.0


def test_dense_grid_full_range_error():
    worst = 0.0
    for k in range(0, 20001):
        t = -200 + k * 1050 / 20000
        r = round(ratio(t) * 1e7)
        worst = max(worst, abs(rtd.temperature_mC(r) - exact_inverse(r / 1e7) * 1000))
    assert worst <= 1.0  # rounding to whole milli-degC dominates


def test_monotonic_and_out_of_range():
    prev = rtd.temperature_mC(rtd._NODES[0])
    for r in range(rtd._NODES[0], rtd._NODES[-1], 997):
        t = rtd.temperature_mC(r)
        assert t >= prev
        prev = t
    assert rtd.temperature_mC(rtd._NODES[0] - 1) == rtd._T_UNDER
    assert rtd.temperature_mC(rtd._NODES[-1] + 1) == rtd._T_OVER
    assert rtd.temperature_mC(0) == rtd._T_UNDER


def test_tables_match_relation():
    for k, r in enumerate(rtd._NODES):
        assert r == round(ratio(-200 + 10 * k) * 1e7)
    for k, c in enumerate(rtd._CURV):
        t = -200 + 10 * k
        assert abs(c - (2 * (ratio(t) + ratio(t + 10)) - 4 * ratio(t + 5)) * 1e7) <= 1


@given(st.integers(min_value=-200000, max_value=850000))
def test_ratio_of_inverts_conversion(t_mc):
    assert abs(rtd.temperature_mC(rtd.ratio_of(t_mc)) - t_mc) <= 1
    assert abs(rtd.ratio_of(t_mc) - ratio(t_mc / 1000) * 1e7) <= 5  # 5e-7 R0 = 0.0013 degC


def test_intermediates_stay_small_ints():
    """Replays temperature_mC's arithmetic with a bound check on every intermediate."""
    lim = 1 << 30
    worst = 0
    for r in range(rtd._NODES[0], rtd._NODES[-1] + 1, 1009):
        lo, hi = 0, len(rtd._NODES) - 1
        while hi - lo > 1:
            mid = (lo + hi) >> 1
            if r < rtd._NODES[mid]:
                hi = mid
            else:
                lo = mid
        d = rtd._NODES[hi] - rtd._NODES[lo]
        dr = r - rtd._NODES[lo]
        x = dr << 10
        q = x // d
        rem = (x - q * d) << 10
        u = (q << 10) + (rem + (d >> 1)) // d
        u15 = u >> 5
        p = u15 * (32768 - u15)
        c = rtd._CURV[lo] * (p >> 15) * 32
        u2 = u + (c + (d >> 1)) // d
        worst = max(worst, abs(x), abs(rem), abs(p), abs(c), abs(u2 * 625), abs(r))
    assert worst < lim
