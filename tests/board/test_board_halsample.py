"""host/board/linuxcnc/halsample.py's MotionSegmenter: position/velocity samples of a known axis motion (written
here as a trapezoid-free profile on a 0.1 s grid) become the run format's motion intervals."""
import pytest

from host.board.linuxcnc.halsample import MotionSegmenter


def _profile(legs, dt=0.1):
    """[(t, position, velocity)] for legs of (duration s, velocity units/s), from position 0 at t 0."""
    out, t, pos = [], 0.0, 0.0
    for duration, v in legs:
        for _ in range(int(round(duration / dt))):
            t += dt
            pos += v * dt
            out.append((round(t, 6), pos, v))
    return out


def _segment(samples, **kw):
    seg = MotionSegmenter(**kw)
    rows = [r for t, p, v in samples for r in seg.sample(t, p, v)]
    return rows + seg.finish()


def test_moves_between_stands_become_intervals():
    rows = _segment(_profile([(1.0, 0.0), (3.0, 100.0), (1.0, 0.0), (4.0, -50.0), (1.0, 0.0)]))
    assert len(rows) == 2
    (a0, a1, af, at, afeed), (b0, b1, bf, bt, bfeed) = rows
    # a move starts at the last standing sample and ends at the first standing one after it
    assert (a0, a1, af, at) == pytest.approx((1.0, 4.1, 0.0, 300.0))
    assert afeed == pytest.approx(6000.0)
    assert (b0, b1, bf, bt) == pytest.approx((5.0, 9.1, 300.0, 100.0)) and bfeed == pytest.approx(3000.0)


def test_a_reversal_without_a_stand_splits_the_move_and_inches_are_converted():
    rows = _segment(_profile([(0.5, 0.0), (2.0, 1.0), (2.0, -2.0)]), units="inch")  # in/s
    assert len(rows) == 2
    (a0, a1, af, at, afeed), (b0, b1, bf, bt, bfeed) = rows
    # +1 in/s from t 0.5 to 2.5 (2 in), then -2 in/s: the first sample going back (t 2.6, 1.8 in) ends the first
    # move and starts the second, which the end of the recording closes at its last sample (t 4.5, -2 in)
    assert (a0, a1, af, at) == pytest.approx((0.5, 2.6, 0.0, 1.8 * 25.4))
    assert (b0, b1, bf, bt) == pytest.approx((2.6, 4.5, 1.8 * 25.4, -2.0 * 25.4))
    assert afeed == pytest.approx(60 * 25.4) and bfeed == pytest.approx(120 * 25.4)


def test_standing_still_is_no_motion():
    assert _segment(_profile([(2.0, 0.0), (1.0, 0.001)])) == []  # below IDLE_MM_PER_S: a servo's dither
