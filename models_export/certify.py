"""Exact interval arithmetic that certifies the integer evaluation (scales, limbs, error intervals, headroom).

Interval arithmetic and the certificate's building blocks (models_export/plan.py applies them kind by kind;
models_export/exact.py reads the document). Everything mirrors firmware/evaluate.py operation by operation (same
order, same limb splits, same shifts). Two things are certified, both with
exact rational arithmetic (``fractions.Fraction``; the model's float
coefficients are converted exactly):

* integer safety: an interval for every intermediate of the firmware's
  evaluation, for every input inside the envelope, must lie inside
  ``|x| <= 2**30 - 1`` (the 31-bit small int of a 32-bit MicroPython port).
  Scales are chosen so that coefficient products stay below 2**29 (one bit of
  margin) and accumulators below 2**28; the ``accs`` intervals (per checked accumulator) are what the
  tests compare with values observed in the firmware's checking mode;
* accuracy: an interval for ``integer result - exact model`` is carried
  through every operation (coefficient quantisation, each floor of a right
  shift, the final rounding), centred by the bias constants (S0, rO, rK, rT,
  rS) and bounded in um.

For the screw recurrence the state error obeys e[k+1] = A e[k] + r[k] with a
per-step residual |r| <= rho (quantisation of C = A - I and B, floors, feed
rounding); clamping the integer state to [0, state_max] is a projection onto
a box that holds the exact state, so it never increases |e|. Hence
|e[k]| <= sum_m |A|^m rho <= v for every k, for any v >= 0 with
v >= |A| v + rho elementwise (the iteration x <- |A| x + rho from 0 is
monotone and stays below such a v). The exporter finds v with a float solve
of (I - |A|) v = rho, inflates it, and verifies v >= |A| v + rho exactly; if
no such v exists (|A| not contracting) it refuses to export.
"""

from __future__ import annotations

from fractions import Fraction
from typing import Union, overload
import math
from fractions import Fraction as F


MAXV = (1 << 30) - 1
PROD = 1 << 29  # coefficient x limb products are kept below this
ACC = 1 << 28  # accumulators (scaled values) are kept below this
MAX_FRAC = 60
OU_PER_UM = 100  # output unit 0.01 um
SLOPE_PER_OU_PER_UM = 10 ** 6  # 1 OU/um = 0.01 um/um = 10**6 x 0.01 um/m
FLOAT_MARGIN_UM = 1e-9  # the float model's own rounding (double precision, |values| < 1e5 um)
LIMITS_UM = {"poly_slope": 0.05, "linear_direct": 0.05, "screw_reduced": 0.1, "dynamic": 0.1}
# the reduced screw form against the full model it came from, RMS on the training runs (docs/table-format.md)
DEFAULT_REDUCTION_LIMIT_UM = 0.5


# an exact number of the analysis, and a closed interval of them (lo, hi)
Num = Union[int, Fraction]
Interval = tuple[Num, Num]
# an interval of the firmware's integers (an accumulator, a limb, a coefficient): what the limb splits and the
# shifts take; the sum and product of integer intervals are integer intervals (iv_add, iv_mul say so)
IntInterval = tuple[int, int]


class ExportError(ValueError):
    """The model cannot be exported; the message names the term and the reason."""


# ------------------------------------------------------------------ helpers
def frac_bits(bound: Num, limit: Num, cap: int = MAX_FRAC) -> int:
    """Largest f <= cap with bound * 2**f <= limit (bound a non-negative Fraction)."""
    bound = F(bound)
    if bound == 0:
        return cap
    ratio = F(limit) / bound
    f = ratio.numerator.bit_length() - ratio.denominator.bit_length()  # within 1 of log2(ratio)
    if f > cap + 1:
        return cap
    while bound * F(2) ** f > limit:
        f -= 1
    while f + 1 <= cap and bound * F(2) ** (f + 1) <= limit:
        f += 1
    return min(f, cap)


def p2(k: int) -> Fraction:
    return F(2) ** k


def rnd(x: float | Fraction) -> int:
    """Round a Fraction to the nearest int (half away from zero)."""
    x = F(x)
    return int(math.floor(x + F(1, 2))) if x >= 0 else -int(math.floor(-x + F(1, 2)))


@overload
def iv_mul(a: IntInterval, b: IntInterval) -> IntInterval: ...
@overload
def iv_mul(a: Interval, b: Interval) -> Interval: ...
def iv_mul(a: Interval, b: Interval) -> Interval:
    c = (a[0] * b[0], a[0] * b[1], a[1] * b[0], a[1] * b[1])
    return (min(c), max(c))


@overload
def iv_add(*ivs: IntInterval) -> IntInterval: ...
@overload
def iv_add(*ivs: Interval) -> Interval: ...
def iv_add(*ivs: Interval) -> Interval:
    return (sum(i[0] for i in ivs), sum(i[1] for i in ivs))


def iv_scale(a: Interval, k: Num) -> Interval:
    return iv_mul(a, (F(k), F(k)))


def iv_abs(a: Interval) -> Num:
    return max(abs(a[0]), abs(a[1]))


def int_iv(real_iv: Interval, err_iv: Interval) -> IntInterval:
    """Integer interval holding real + err."""
    return (math.floor(real_iv[0] + err_iv[0]), math.ceil(real_iv[1] + err_iv[1]))


def limbs(x: IntInterval, L: int, n: int) -> list[IntInterval]:
    """Intervals of the limbs of x (an int interval) split as the firmware's _mul does."""
    out = [(0, (1 << L) - 1)] * (n - 1)
    out.append((x[0] >> (L * (n - 1)), x[1] >> (L * (n - 1))))
    return out


def limb_max(x: IntInterval, L: int, n: int) -> int:
    return max(max(abs(a), abs(b)) for a, b in limbs(x, L, n))


def top_limbs_needed(x: IntInterval, L: int, narrow: Num) -> int | None:
    """Smallest limb count n such that narrow * |top limb| <= PROD."""
    for n in range(1, 7):
        top = max(abs(x[0] >> (L * (n - 1))), abs(x[1] >> (L * (n - 1))))
        if narrow * top <= PROD:
            return n
    return None


def narrow_width(narrow: Num) -> int:
    """Limb width L for a wide operand multiplied by |narrow| <= narrow: narrow * (2**L - 1) <= PROD."""
    if narrow <= 0:
        return 29
    L = 0
    while L < 29 and narrow * ((1 << (L + 1)) - 1) <= PROD:
        L += 1
    return L


def fit_coef(value: Fraction, limbmax: Num, base_frac: int, cap: int = 62) -> tuple[int, int]:
    """Quantise ``value`` (a Fraction) as q = round(value * 2**(base_frac + sh)) with the largest
    shift sh <= cap such that |q| * limbmax <= PROD. Returns (q, sh); (0, 0) for a zero value."""
    if value == 0:
        return 0, 0
    limbmax = max(limbmax, 1)  # a zero operand range still needs |q| <= PROD
    sh = frac_bits(abs(value) * p2(base_frac) * limbmax, PROD, cap=cap)
    while True:
        q = rnd(value * p2(base_frac + sh))
        if q == 0:
            return 0, 0  # below the resolution of the result: the term's error is its whole value
        if abs(q) * limbmax <= PROD:
            return q, sh
        sh -= 1


class Recorder:
    """Interval of every checked firmware accumulator (firmware/evaluate.py ACC_*), and the peak |integer| each named term produces."""

    def __init__(self) -> None:
        self.accs: dict[int, IntInterval] = {}  # accumulator (ACC_*; -1 the constants) -> its interval
        self.peaks: dict[str, int] = {}  # term -> the largest |integer| it produces

    def note(self, acc_id: int, lo: int, hi: int, term: str) -> None:
        cur = self.accs.get(acc_id)
        self.accs[acc_id] = (lo, hi) if cur is None else (min(cur[0], lo), max(cur[1], hi))
        m = max(abs(lo), abs(hi))
        if m > self.peaks.get(term, -1):
            self.peaks[term] = m
        if m > MAXV:
            raise ExportError("term %s: an intermediate of the integer evaluation reaches %d (2^%.2f), beyond the "
                              "small-int limit 2^30; the model cannot be made integer-safe over its envelope"
                              % (term, m, math.log2(m)))

    def mul(self, acc_id: int, c: IntInterval, x: IntInterval, L: int, n: int, sh: int, term: str) -> tuple[IntInterval, int]:
        """Mirror of Evaluator._mul: returns (result interval, number of flooring shifts)."""
        rlo = rhi = 0
        s = sh
        floors = 0
        for lo, hi in limbs(x, L, n):
            cand = (c[0] * lo, c[0] * hi, c[1] * lo, c[1] * hi)
            plo, phi = min(cand), max(cand)
            self.note(acc_id, plo, phi, term)
            if s > 0:
                tlo, thi = plo >> s, phi >> s
                floors += 1
            else:
                tlo, thi = plo << -s, phi << -s
            rlo += tlo
            rhi += thi
            self.note(acc_id + 1, tlo, thi, term)
            self.note(acc_id + 1, rlo, rhi, term)
            s -= L
        return (rlo, rhi), floors

    def headroom(self, term: str) -> float:
        m = self.peaks.get(term, 0)
        return 30.0 - math.log2(m) if m > 0 else 30.0


def floor_err(k: int) -> Interval:
    """Error interval of k flooring right shifts."""
    return (F(-k), F(0))


def center(err: Interval) -> int:
    """Integer bias that centres an error interval on zero (subtracted from the value)."""
    return rnd(-(err[0] + err[1]) / 2)
