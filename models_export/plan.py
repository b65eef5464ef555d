"""Choose scales, quantise and certify, kind by kind, in the firmware's evaluation order.

``Planner(model)`` then ``linear_direct()`` or ``positional()`` returns the error
interval of every output; afterwards ``f`` holds the table fields
(models_export.tableformat.pack), ``terms`` the per-term scales and error
contributions and ``rec`` (a certify.Recorder) the accumulator intervals and headroom
(models_export.certify explains the argument).
"""

from __future__ import annotations

from collections.abc import Sequence
from fractions import Fraction
from typing import Any, TypedDict, overload
from models_export.certify import IntInterval, Interval, Num
from typing import TYPE_CHECKING
import math
from fractions import Fraction as F

import numpy as np

# The ignores: firmware/evaluate.py defines these as _NAME consts (free on MicroPython) and publishes them under
# NAME on CPython only (its globals() loop), which pyright cannot see
from firmware.evaluate import (
    ACC_AMUL, ACC_BMUL, ACC_CMUL, ACC_CONVY, ACC_CUM, ACC_CUMMUL, ACC_D, ACC_DE, ACC_DMUL, ACC_DX, ACC_EMUL, ACC_FEEDMUL,  # pyright: ignore[reportAttributeAccessIssue]
    ACC_GEO, ACC_GEOMUL, ACC_GMUL, ACC_HMUL, ACC_KMUL, ACC_LIMB, ACC_LMUL, ACC_NMUL, ACC_NSUM, ACC_OMUL, ACC_OSUM, ACC_OUT, ACC_P, ACC_PMUL, ACC_QMUL, ACC_ROW,  # pyright: ignore[reportAttributeAccessIssue]
    ACC_ROWMUL, ACC_S, ACC_SEGMUL, ACC_SLOPE, ACC_SMUL, ACC_STATE, ACC_SUM, ACC_THMUL, ACC_TRAVEL, ACC_UGMUL, ACC_XL, ACC_Y,  # pyright: ignore[reportAttributeAccessIssue]
    ACC_YMUL, FEED_LIMB, FEED_W_BITS,  # pyright: ignore[reportAttributeAccessIssue]
)
from models_export.certify import (
    ACC, OU_PER_UM, PROD, SLOPE_PER_OU_PER_UM, ExportError, Recorder, center, fit_coef, floor_err, frac_bits,
    int_iv, iv_abs, iv_add, iv_mul, iv_scale, limb_max, limbs, narrow_width, p2, rnd, top_limbs_needed,
)

from models_export.exact import power_chain

if TYPE_CHECKING:
    from models_export.exact import Model

ZERO: Interval = (F(0), F(0))
EPS_BITS = 24  # moving_convection: the step's extra convection weight D_i*U is held below 2**EPS_BITS


def _c(x: Num) -> Interval:
    """The point interval of one exact number."""
    x = F(x)
    return (x, x)


# the hull and the meet of integer intervals are integer intervals (the accumulators' bounds stay ints)
@overload
def _hull(*ivs: IntInterval) -> IntInterval: ...
@overload
def _hull(*ivs: Interval) -> Interval: ...
def _hull(*ivs: Interval) -> Interval:
    return (min(i[0] for i in ivs), max(i[1] for i in ivs))


@overload
def _meet(a: IntInterval, b: IntInterval) -> IntInterval: ...
@overload
def _meet(a: Interval, b: Interval) -> Interval: ...
def _meet(a: Interval, b: Interval) -> Interval:
    lo, hi = max(a[0], b[0]), min(a[1], b[1])
    return (lo, hi) if lo <= hi else a


def _round_out(err: Interval, f: int, r: int | None = None) -> tuple[int, Interval]:
    """Error interval of floor((acc + r) / 2**f) given acc's error interval ``err`` (acc units); returns (r, err_out).
    ``r`` None: the bias that centres the interval."""
    if r is None:
        r = rnd(-(err[0] + err[1]) / 2 + F((1 << f) - 1, 2))
    lo = (err[0] + r) / p2(f) - F((1 << f) - 1, 1 << f)
    hi = (err[1] + r) / p2(f)
    return r, (lo, hi)


# one term of S (s_block, dyn_coefficients): (integer result interval, name, scale, |quantisation|, error interval)
SPart = tuple[IntInterval, str, int, Num, Interval]


class Term(TypedDict):
    """One term's line of the certificate (Planner.term; export.py reports it)."""
    name: str
    scale: int  # the power of two of its integer coefficient
    key: str  # the Recorder's name of the term (its headroom)
    err_ou: Fraction  # its error contribution to the offset, output units (0.01 um)


class ReducedScrew(TypedDict):
    """thermal.reduced as Planner.screw_prepare read and checked it, in the units the screw planning uses."""
    M: int  # segments
    A: np.ndarray  # M x M state transition
    B: np.ndarray  # M heat per mm of the segment's travel (K/mm)
    edges: list[float]  # M + 1 segment edges (mm)
    edges_um: list[int]  # ... rounded to whole um (the table's)
    fixed: float  # fixed end (mm)
    fe: int  # ... rounded to whole um
    Tmax: Fraction  # the state's range (K): [Tlo, Tmax]
    Tlo: Fraction
    umax: int  # travel per step at the top feed (um)
    air: int  # the air sensor's channel, -1 without one
    c0: list[Fraction]  # air weights at the step's start and end
    c1: list[Fraction]
    d_air: IntInterval  # the air's range over its reference (mK)
    Bu: list[Fraction]  # heat per mm of the step's total travel (K/mm)
    rev: Fraction  # reversal term (um)
    g0: Fraction | None  # speed_dependent_heat: g(U) = g0 + gv U; g0 None without it
    gv: Fraction  # (per um; 0 without speed_dependent_heat, where nothing reads it)
    D: list[Fraction]  # moving_convection: extra convection weight per um of the step's travel


class Planner:
    def __init__(self, model: Model) -> None:
        self.m = model
        self.rec = Recorder()
        self.f: dict[str, Any] = {}  # the table's fields by name (ints, lists of ints): tableformat.pack
        self.terms: list[Term] = []
        self.obs_cert: list[dict[str, Any]] | None = None  # dynamic tables with an observer: per lag state, its certified start (dyn_observer)
        self.obs_e0: dict[int, Num] = {}  # filter index -> |start error| (state units)
        self.obs_start_um: Num | None = None  # the observer's start error carried to the offset (um)
        self.sobs_cert: dict[str, Any] | None = None  # screw tables with an observer: its certified start (screw_observer)
        # set by the kind's planning (declared here for their types): the dynamic filters' and the screw state's
        # certificates (report entries), and thermal.reduced as read (screw_prepare)
        self.dyn_cert: list[dict[str, Any]]
        self.state_cert: dict[str, Any]
        self.s: ReducedScrew

    def term(self, name: str, scale: int, err_ou: Num, key: str | None = None) -> None:
        """Record one term's error contribution to the offset; ``err_ou`` is in output units (0.01 um), never in
        accumulator units: callers divide accumulator-scale errors by 2**fo (export.py reports err_ou / 100 um)."""
        self.terms.append({"name": name, "scale": scale, "key": key or name, "err_ou": F(err_ou)})

    # ------------------------------------------------------------ S = S0 + sum b*d
    def s_block(self, fS: int, out_factor: Num) -> tuple[IntInterval, Interval]:
        """Temperature-linear accumulator at scale 2**fS; out_factor converts its error to output units."""
        m, rec, f = self.m, self.rec, self.f
        n = len(m.sensors)
        dmax = max([max(abs(a), abs(b)) for a, b in zip(m.d_lo[:n], m.d_hi[:n])] + [1])
        nt = 1 if dmax.bit_length() <= 10 else 2
        Lt = max(1, min(29, -(-dmax.bit_length() // nt)))
        f.update(Lt=Lt, nt=nt, fS=fS, b=[], shb=[], fb=[])
        err = ZERO
        parts: list[SPart] = []
        if m.kind == "dynamic":
            y_err = self.dyn_filters()
            self.dyn_coefficients(fS, y_err, out_factor, parts)
            err = iv_add(err, *[e for _, _, _, _, e in parts])
        for i in range(n):
            d = (m.d_lo[i], m.d_hi[i])
            rec.note(ACC_D, d[0], d[1], "temperatures")
            lm = limb_max(d, Lt, nt)
            q, sh = fit_coef(m.b[i], lm, fS)
            f["b"].append(q)
            f["shb"].append(sh)
            f["fb"].append(fS + sh)
            res, k = rec.mul(ACC_SMUL, (q, q), d, Lt, nt, sh, m.b_names[i])
            quant = iv_scale((F(d[0]), F(d[1])), F(q) / p2(sh) - m.b[i] * p2(fS))
            err = iv_add(err, quant, floor_err(k))
            parts.insert(i, (res, m.b_names[i], fS + sh, iv_abs(quant), ZERO))
            self.term(m.b_names[i], fS + sh, iv_abs(quant) * out_factor)
        bias = center(err)
        S0 = rnd(m.b0 * p2(fS)) + bias
        f["S0"] = S0
        e0 = F(S0) - m.b0 * p2(fS)
        eS = iv_add(err, _c(e0))
        self.term("S0 (%s)" % ("intercept_um" if m.direct else "intercept_um_per_mm"), fS,
                  abs(e0 - bias) * out_factor, key="S0")
        rec.note(-1, S0, S0, "S0")  # -1: constants (no firmware accumulator)
        acc = (S0, S0)
        for res, name, _, _, _ in parts:
            acc = iv_add(acc, res)
            rec.note(ACC_S, acc[0], acc[1], name)
        s_real = m.s_range()
        S_iv = _meet(acc, int_iv((s_real[0] * p2(fS), s_real[1] * p2(fS)), eS))
        return S_iv, eS

    # ------------------------------------------------------------ dynamic
    def dyn_filters(self) -> list[Interval]:
        """Quantise every lag filter and certify its state; returns the per-term error interval of the integer state
        against the exact recurrence on the exact inputs (state units).

        The state error obeys e[k+1] = (1 - a) e[k] + r[k] with |r| <= rho: the quantisation of a times
        |U0 << fy - Y| (both in the state box, so at most its width) and the increment's floors, centred by rA.
        Clamping to the box, which holds the exact state (a convex combination of the inputs and the rest
        state 0), cannot increase |e|. A v with v >= (1 - a) v + rho (the screw's _supersolution, verified
        exactly) bounds |e| at every step from the cold start (e = 0): over an unbounded horizon."""
        m, f, rec = self.m, self.f, self.rec
        terms = m.dyn
        R = max([(t["u"][1] - t["u"][0]) << t["fy"] for t in terms] + [1])
        nX = 3
        LX = max(1, -(-R.bit_length() // nX))
        nY = 2
        big = max([max(-lo, hi) for lo, hi in zip(m.d_lo[len(m.sensors):], m.d_hi[len(m.sensors):])] + [1])
        LY = max(1, -(-big.bit_length() // nY))
        Lq, nq = m.Lq, m.nq
        q_iv, kq = rec.mul(ACC_QMUL, (0, m.smax), (0, m.smax), Lq, nq, m.shq, "spindle speed squared")
        f.update(positional=0 if m.direct else 1, dt_ms=m.dt_ms, smax=m.smax, Lq=Lq, nq=nq, shq=m.shq, fmax=m.fmax, Lp=m.Lp, np=m.np, shp2=m.shp2, shp=m.shp,
                 LX=LX, nX=nX, LY=LY, nY=nY, nf=len(terms), src=[], A=[], shA=[], gA=[], rA=[], fy=[], Ylo=[], Yhi=[])
        out = []
        self.dyn_cert = []
        uin = []  # per filter: its integer input minus the exact one (input units), for the observer
        for t in terms:
            fy, a = t["fy"], t["a"]
            Ylo, Yhi = t["u"][0] << fy, t["u"][1] << fy
            rec.note(ACC_Y, Ylo, Yhi, t["name"])
            ein = ZERO
            if t["src"] >= 0:  # the rise d = T - round(reference): the exact one is T - reference_C (the observer's)
                fr = m.ref_frac[t["src"]]
                uin.append((fr, fr))
            elif t["src"] > -2:
                uin.append(ZERO)
            if t["src"] == -2:  # rpm**2 floored limb by limb: the input is low by less than kq units
                ein = (F(-kq) * p2(fy), F(0))
                uin.append((F(-kq), F(0)))
                if q_iv[1] > t["u"][1]:
                    raise ExportError("%s: the squared speed exceeds its box" % t["name"])
            elif t["src"] <= -4:  # a power of a rise, floored factor by factor (models_export.exact.power_chain)
                i, e = (-4 - t["src"]) // 3, (-4 - t["src"]) % 3 + 2
                u, err, _ = power_chain(rec, (m.d_lo[i], m.d_hi[i]), e, m.Lp, m.np, m.shp2, m.shp, t["name"], ACC_PMUL)
                if u[0] < t["u"][0] or u[1] > t["u"][1]:
                    raise ExportError("%s: the power exceeds its box" % t["name"])
                ein = (err[0] * p2(fy), err[1] * p2(fy))
                uin.append(err)
            elif t["src"] == -3:
                uin.append(ZERO)
            f["src"].append(t["src"])
            f["fy"].append(fy)
            f["Ylo"].append(Ylo)
            f["Yhi"].append(Yhi)
            if a == 0:  # tau = 0: the state is the input itself, exactly
                f["A"].append(0)
                f["shA"].append(0)
                f["gA"].append(0)
                f["rA"].append(0)
                out.append(ein)
                self.dyn_cert.append({"term": t["name"], "a": 0.0, "state_error_units": 0.0})
                continue
            X = (Ylo - Yhi, Yhi - Ylo)
            rec.note(ACC_DX, X[0], X[1], t["name"])
            q, sh = fit_coef(a, limb_max(X, LX, nX), 0)
            if q <= 0:
                raise ExportError("%s: the step %d ms is too small against the time constant for the table" % (t["name"], m.dt_ms))
            aq = F(q) / p2(sh)
            # guard bits: the increment a*X (at most aq*|X|) is summed g bits finer, then rounded once
            g = max(0, min(sh, 24, frac_bits(aq * (Yhi - Ylo) + 1, ACC)))
            res, k = rec.mul(ACC_DMUL, (q, q), X, LX, nX, sh - g, t["name"])
            rA, e_inc = _round_out(floor_err(k), g)
            rec.note(ACC_DMUL + 1, res[0] + rA, res[1] + rA, t["name"])
            rho = abs(aq - a) * (Yhi - Ylo) + iv_abs(e_inc)
            rec.note(ACC_Y, Ylo + ((res[0] + rA) >> g), Yhi + ((res[1] + rA) >> g), t["name"])
            v = _supersolution(np.array([[1.0 - float(a)]]), [rho])
            if v is None or not v[0] >= (1 - a) * v[0] + rho:
                raise ExportError("%s: the filter's state error cannot be bounded" % t["name"])
            f["A"].append(q)
            f["shA"].append(sh)
            f["gA"].append(g)
            f["rA"].append(rA)
            out.append(iv_add((-v[0], v[0]), ein))
            self.dyn_cert.append({"term": t["name"], "a": float(a), "a_quantised": float(aq), "per_step_residual_units": float(rho),
                                  "state_error_units": float(v[0]), "state_frac_bits": fy})
        return self.dyn_observer(out, uin)

    def dyn_observer(self, out: list[Interval], uin: list[Interval]) -> list[Interval]:
        """Quantise and certify the observer (Evaluator.observe); returns the state error intervals ``out`` widened to
        cover the observer's start.

        Row j: acc = rG[j] + sum_m mul(Go, Uc[m], LO, nO, shO - gO[j]) at gO[j] guard bits, then >> gO[j] and clamped
        to the state box. Its error against the exact estimate sum_m c_jm u*_m (u* the exact inputs, ``uin`` their
        difference from the integer ones) is quantisation, input error and floors, centred by rG and rounded once:
        an interval E0_j. The exact start is that estimate clamped to the box (a projection: |error| does not grow,
        and from a start inside the box the exact state stays in it). The filter's error then obeys
        |e[k+1]| <= (1 - a)|e[k]| + rho from |e[0]| <= |E0_j|, so V = max(v, |E0_j|) (v >= (1 - a) v + rho, hence
        V >= (1 - a) V + rho) bounds it at every step after the estimate."""
        m, f, rec = self.m, self.f, self.rec
        terms = m.dyn
        nf = len(terms)
        R = max([max(-t["u"][0], t["u"][1]) for t in terms] + [1])
        nO = 2
        LO = max(1, -(-R.bit_length() // nO))
        f.update(obs=0, settle_s=0, LO=LO, nO=nO, Go=[0] * (nf * nf), shO=[0] * (nf * nf), gO=[0] * nf, rG=[0] * nf,
                 tauc=[0] * nf, settle_nr=0)
        self.obs_cert = None
        G = getattr(m, "obs_gain", None)
        if G is None:
            return out
        f.update(obs=1, settle_s=m.settle_s, settle_nr=m.settle_nr_s)
        self.obs_cert = []
        supplied = getattr(m, "supplied", {})
        for j, t in enumerate(terms):
            if t["a"] == 0:
                continue
            if j in supplied:
                f["tauc"][j] = supplied[j]
                if not any(G[j]):
                    # no estimate: until the controller's values come the state is its present input (Evaluator.observe),
                    # exact within the input's error, which v + |ein| covers; the controller sends round(its lag x
                    # 2**scale) in state units (host/board/supplied.py): the start is the exact state within half a unit,
                    # inside the box (the board refuses a value outside it)
                    e0 = (F(-1, 2), F(1, 2))
                    self.obs_e0[j] = iv_abs(e0)
                    V = max(iv_abs(out[j]), iv_abs(e0))
                    if V > iv_abs(out[j]):
                        out[j] = (-V, V)
                    self.obs_cert.append({"term": t["name"], "filter": j, "supplied_by": "controller", "tau_ms": supplied[j],
                                          "start_error_units": 0.5, "start_error_signal_units": float(F(1, 2) / p2(t["fy"]) * t["per"]),
                                          "state_box_units": [t["u"][0] << t["fy"], t["u"][1] << t["fy"]],
                                          "estimate_clamped_in_envelope": False})
                    continue
            bound = sum(abs(G[j][k]) * max(-terms[k]["u"][0], terms[k]["u"][1]) for k in range(nf))
            # the row's scale 2**g: guard bits (g > 0), or coarser than the state (g < 0) for an estimate that can reach far
            # beyond the state's box over the envelope (gains on temperatures into a spindle state, say)
            g = frac_bits(bound + 1, ACC, cap=24)
            if g < -28:
                raise ExportError("%s: the observer's estimate (up to %.3g state units) is too large for the table" % (t["name"], float(bound)))
            err = ZERO
            qs = []
            for k in range(nf):
                u = terms[k]["u"]
                q, sh = fit_coef(G[j][k], limb_max(u, LO, nO), g) if G[j][k] else (0, 0)
                qs.append((q, sh))
                if q == 0:
                    err = iv_add(err, iv_scale((F(u[0]), F(u[1])), -G[j][k] * p2(g)), iv_scale(uin[k], -G[j][k] * p2(g)))
                    continue
                qv = F(q) / p2(sh)
                # integer q x Uc / 2**sh (floored) against c 2**g u*: (qv - c 2**g) Uc + c 2**g (Uc - u*) + floors
                _, nfl = rec.mul(ACC_OMUL, (q, q), u, LO, nO, sh, t["name"] + " observer")
                err = iv_add(err, iv_scale((F(u[0]), F(u[1])), qv - G[j][k] * p2(g)), iv_scale(uin[k], G[j][k] * p2(g)),
                             floor_err(nfl))
            if g >= 0:
                r, e0 = _round_out(err, g)
            else:  # acc clamped to the box at scale 2**g (within 1 of the exact box), then shifted up: no rounding
                r = center(err)
                e0 = iv_scale(iv_add(err, _c(r), (F(-1), F(1))), p2(-g))
            acc = (r, r)
            for k, (q, sh) in enumerate(qs):
                if q:
                    res, _ = rec.mul(ACC_OMUL, (q, q), terms[k]["u"], LO, nO, sh, t["name"] + " observer")
                    acc = iv_add(acc, res)
                    rec.note(ACC_OSUM, acc[0], acc[1], t["name"] + " observer")
                    f["Go"][j * nf + k] = q
                    f["shO"][j * nf + k] = sh + g
            f["gO"][j] = g
            f["rG"][j] = r
            if j in supplied:  # the start is this estimate (no controller's values) or the controller's, within 1/2 unit
                e0 = (min(e0[0], F(-1, 2)), max(e0[1], F(1, 2)))
            self.obs_e0[j] = iv_abs(e0)
            fy = t["fy"]
            Ylo, Yhi = t["u"][0] << fy, t["u"][1] << fy
            if g >= 0:
                rec.note(ACC_Y, acc[0] >> g, acc[1] >> g, t["name"] + " observer")
            else:
                rec.note(ACC_Y, max(acc[0], Ylo >> -g) << -g, min(acc[1], Yhi >> -g) << -g, t["name"] + " observer")
            # where the exact estimate can leave the state box (over the certified envelope) the board starts at the box
            est = iv_add(*[iv_scale((F(terms[k]["u"][0]), F(terms[k]["u"][1])), G[j][k]) for k in range(nf)])
            # the error e (input errors ein and arithmetic) obeys |e'| <= (1 - a)|e| + a|ein| + rho with v >= rho / a,
            # so V = max(v + |ein|, |E0|) is kept by every step
            V = max(iv_abs(out[j]), iv_abs(e0))
            if V > iv_abs(out[j]):
                out[j] = (-V, V)
            self.obs_cert.append({"term": t["name"], "filter": j, "guard_bits": g, "start_error_units": float(iv_abs(e0)),
                                  **({"supplied_by": "controller", "tau_ms": supplied[j]} if j in supplied else {}),
                                  "start_error_signal_units": float(iv_abs(e0) / p2(fy) * t["per"]),
                                  "estimate_units_over_envelope": [float(est[0]), float(est[1])], "state_box_units": [Ylo, Yhi],
                                  "estimate_clamped_in_envelope": bool(est[0] < Ylo or est[1] > Yhi)})
        return out

    def dyn_coefficients(self, fS: int, y_err: list[Interval], out_factor: Num, parts: list[SPart]) -> None:
        """bY[j] x Y[j] into S (scale 2**fS); parts gets (result, name, scale, |quantisation|, error interval)."""
        m, f, rec = self.m, self.f, self.rec
        n = len(m.sensors)
        f.update(bY=[], shY=[])
        for j, t in enumerate(m.dyn):
            B = m.b[n + j]
            Yiv = (m.d_lo[n + j], m.d_hi[n + j])
            q, sh = fit_coef(B, limb_max(Yiv, f["LY"], f["nY"]), fS)
            f["bY"].append(q)
            f["shY"].append(sh)
            res, k = rec.mul(ACC_YMUL, (q, q), Yiv, f["LY"], f["nY"], sh, t["name"])
            qv = F(q) / p2(sh)
            quant = iv_scale((F(Yiv[0]), F(Yiv[1])), qv - B * p2(fS))
            err = iv_add(quant, iv_scale(y_err[j], qv), floor_err(k))
            parts.append((res, t["name"], fS + sh, iv_abs(quant), err))
            if j in self.obs_e0:
                self.obs_start_um = (self.obs_start_um or 0) + abs(qv) * self.obs_e0[j] * out_factor / OU_PER_UM
            self.term(t["name"], fS + sh, (iv_abs(quant) + iv_abs(iv_scale(y_err[j], qv))) * out_factor)

    # ------------------------------------------------------------ kinds
    def linear_direct(self) -> dict[str, Interval]:
        m, f, rec = self.m, self.f, self.rec
        bound = max(m.s_bound(), iv_abs(m.s_range()))
        fo = frac_bits(bound, ACC, cap=24)
        if fo < 0:
            raise ExportError("%s: the offset range %.4g um exceeds what the table can hold" % (_largest(m), float(bound) / OU_PER_UM))
        f["fo"] = fo
        S_iv, eS = self.s_block(fo, F(1, 1 << fo))
        rL, err_out = _round_out(eS, fo)
        f["rL"] = rL
        rec.note(ACC_SUM, S_iv[0] + rL, S_iv[1] + rL, "output")
        out = ((S_iv[0] + rL) >> fo, (S_iv[1] + rL) >> fo)
        rec.note(ACC_OUT, out[0], out[1], "output")
        f.update(cert_out=_mag(out), cert_ref=_mag(out), cert_slope=0)
        self.term("output rounding (2^-%d)" % fo, fo, F(1, 2), key="output")
        return {"offset": err_out, "ref_offset": err_out, "slope": ZERO}

    def positional(self) -> dict[str, Interval]:
        m, f, rec = self.m, self.f, self.rec
        screw = m.kind == "screw_reduced"
        P = m.p_iv()
        PM = max(abs(m.pos_lo), abs(m.pos_hi), 1)
        if PM > PROD:
            raise ExportError("envelope.position_mm: |position| up to %d um does not fit the table" % PM)
        seg_bound = self.screw_prepare() if screw else F(0)
        rev_ou = abs(self.s["rev"]) * OU_PER_UM if screw else F(0)  # the reversal term (output units)
        geo_bound = iv_abs(m.horner_range(0))
        acc_bound = geo_bound + m.s_bound() * PM + seg_bound + rev_ou
        fo = frac_bits(acc_bound, ACC, cap=24)
        if fo < 0:
            raise ExportError("%s: the offset range %.4g um over the envelope exceeds what the table can hold"
                              % (_largest(m, PM, seg_bound), float(acc_bound) / OU_PER_UM))
        f["fo"] = fo
        f["rL"] = 0
        fS = frac_bits(m.s_bound(), ACC)
        S_iv, eS = self.s_block(fS, F(PM) / p2(fS))
        rec.note(ACC_P, m.pos_lo, m.pos_hi, "position")
        Lw = narrow_width(PM)
        nw = top_limbs_needed(S_iv, Lw, PM)
        if nw is None:
            raise ExportError("%s: slope x position cannot be split into small-int limbs" % _largest(m, PM))
        shw = fS - fo
        f.update(Lw=Lw, nw=nw, shw=shw)
        th, k = rec.mul(ACC_THMUL, (m.pos_lo, m.pos_hi), S_iv, Lw, nw, shw, "slope x position")
        err_th = iv_add(iv_scale(iv_mul(P, eS), 1 / p2(shw)), floor_err(k))
        self.term("rounding: slope x position", fo, F(k) / p2(fo), key="slope x position")  # k floors of one acc unit
        # geometric polynomial, Horner in p (um)
        h_iv, err_geo = self.horner(fo, PM)
        # screw segments
        if screw:
            seg_iv, err_seg = self.screw_state(fo)
        else:
            seg_iv, err_seg = (0, 0), ZERO
        acc = iv_add(h_iv, th)
        rec.note(ACC_SUM, acc[0], acc[1], "output")
        err_rev = ZERO
        if screw:
            acc = iv_add(acc, seg_iv)
            rec.note(ACC_SUM, acc[0], acc[1], "output")
            # reversal: +Rv or -Rv by the direction of the last position change (or 0)
            Rv = rnd(self.s["rev"] * OU_PER_UM * p2(fo))
            f["Rv"] = Rv
            acc = (acc[0] - abs(Rv), acc[1] + abs(Rv))
            rec.note(ACC_SUM, acc[0], acc[1], "output")
            dq = abs(F(Rv) - self.s["rev"] * OU_PER_UM * p2(fo))
            err_rev = (-dq, dq)
            self.term("thermal.reduced.reversal_um", fo, dq / p2(fo))
        err_acc = iv_add(err_geo, err_th, err_seg, err_rev)
        rO, err_out = _round_out(err_acc, fo)
        f["rO"] = rO
        acc = (acc[0] + rO, acc[1] + rO)
        rec.note(ACC_SUM, acc[0], acc[1], "output")
        rec.note(ACC_OUT, acc[0] >> fo, acc[1] >> fo, "output")
        f["cert_out"] = _mag((acc[0] >> fo, acc[1] >> fo))
        self.term("output rounding (2^-%d)" % fo, fo, F(1, 2), key="output")
        # the pair: thermal offset at the reference position ...
        # certified for any reference position inside the envelope (Evaluator.set_reference), not only pos_ref
        th_ref, k = rec.mul(ACC_THMUL, (m.pos_lo, m.pos_hi), S_iv, Lw, nw, shw, "slope x position")
        err_ref = iv_add(iv_scale(iv_mul(P, eS), 1 / p2(shw)), floor_err(k))
        acc_ref = th_ref
        if screw:
            acc_ref = iv_add(acc_ref, seg_iv)
            err_ref = iv_add(err_ref, err_seg)
        rT, err_ref_out = _round_out(err_ref, fo)
        f["rT"] = rT
        rec.note(ACC_SUM, acc_ref[0] + rT, acc_ref[1] + rT, "output")
        rec.note(ACC_OUT, (acc_ref[0] + rT) >> fo, (acc_ref[1] + rT) >> fo, "output")
        f["cert_ref"] = _mag(((acc_ref[0] + rT) >> fo, (acc_ref[1] + rT) >> fo))
        # ... and the thermal slope in 0.01 um/m
        s_real = m.s_range()
        slope_bound = m.s_bound() * SLOPE_PER_OU_PER_UM
        span = m.pos_hi - m.pos_lo
        if screw and span > 0:
            slope_bound += 2 * seg_bound * SLOPE_PER_OU_PER_UM / span
        fK = frac_bits(slope_bound, ACC, cap=24)
        if fK < 0:
            raise ExportError("%s: thermal slope range exceeds what the table can hold" % _largest(m))
        lmw = limb_max(S_iv, Lw, nw)
        KS, shK = fit_coef(F(SLOPE_PER_OU_PER_UM), lmw, fK - fS)
        f.update(KS=KS, shK=shK, fK=fK)
        sl, k = rec.mul(ACC_KMUL, (KS, KS), S_iv, Lw, nw, shK, "KS (slope unit conversion)")
        kq = F(KS) / p2(shK)
        err_sl = iv_add(iv_scale((s_real[0] * p2(fS), s_real[1] * p2(fS)), kq - SLOPE_PER_OU_PER_UM * p2(fK - fS)),
                        iv_scale(eS, kq), floor_err(k))
        self.term("KS (slope unit conversion)", fK - fS + shK, 0, key="KS (slope unit conversion)")
        if screw:
            sl2, err_sl2 = self.screw_chord(seg_iv, err_seg, fo, fK)
            sl = iv_add(sl, sl2)
            err_sl = iv_add(err_sl, err_sl2)
            rec.note(ACC_SLOPE, sl[0], sl[1], "output")
        else:
            self.f.update(KC=0, Lc=1, nc=1, shC=0)
        rK, err_sl_out = _round_out(err_sl, fK)
        f["rK"] = rK
        rec.note(ACC_SLOPE, sl[0] + rK, sl[1] + rK, "output")
        rec.note(ACC_OUT, (sl[0] + rK) >> fK, (sl[1] + rK) >> fK, "output")
        f["cert_slope"] = _mag(((sl[0] + rK) >> fK, (sl[1] + rK) >> fK))
        return {"offset": err_out, "ref_offset": err_ref_out, "slope": err_sl_out}

    def horner(self, fo: int, PM: int) -> tuple[IntInterval, Interval]:
        m, f, rec = self.m, self.f, self.rec
        d = len(m.g) - 1
        fr = [fo]
        for j in range(1, d + 1):  # high powers need many fraction bits; the shifts between levels stay ~log2(PM)
            fr.append(min(frac_bits(iv_abs(m.horner_range(j)), ACC, cap=400), fr[-1] + 62))
        G = [rnd(m.g[j] * p2(fr[j])) for j in range(d + 1)]
        shg = [fr[j + 1] - fr[j] for j in range(d)]
        P = m.p_iv()
        Lg = narrow_width(PM)
        f.update(degree=d, Lg=Lg, G=G, fG=fr, shg=shg)
        names = ["geometric.coefficients_um[%d]" % j for j in range(d + 1)]
        for j in range(d + 1):
            rec.note(-1, G[j], G[j], names[j])
            self.term(names[j], fr[j], abs(F(G[j]) - m.g[j] * p2(fr[j])) * F(PM) ** j / p2(fr[j]))
        for ng in range(1, 7):
            try:
                sub = Recorder()
                h = (G[d], G[d])
                err = _c(F(G[d]) - m.g[d] * p2(fr[d]))
                for j in range(d - 1, -1, -1):
                    nh = top_limbs_needed(h, Lg, PM)
                    if nh is None or nh > ng:
                        raise _Retry()
                    res, k = sub.mul(ACC_GEOMUL, (m.pos_lo, m.pos_hi), h, Lg, ng, shg[j], names[j + 1])
                    err = iv_add(iv_scale(iv_mul(P, err), 1 / p2(shg[j])), floor_err(k), _c(F(G[j]) - m.g[j] * p2(fr[j])))
                    hr = m.horner_range(j)
                    h = _meet(iv_add(res, (G[j], G[j])), int_iv((hr[0] * p2(fr[j]), hr[1] * p2(fr[j])), err))
                    sub.note(ACC_GEO, h[0], h[1], names[j])
                break
            except _Retry:
                continue
        else:
            raise ExportError("geometric.coefficients_um: the polynomial cannot be evaluated in small-int limbs")
        f["ng"] = ng
        _merge(rec, sub)
        return h, err

    # ------------------------------------------------------------ screw_reduced
    def screw_prepare(self) -> Fraction:
        """Read thermal.reduced; returns the bound of the segment elongation in output units."""
        m, f = self.m, self.f
        red = m.red
        try:
            M = int(red["segments"])
            A = np.asarray(red["A"], dtype=float)
            B = np.asarray(red["B_K_per_mm"], dtype=float)
            edges = [float(e) for e in red["edges_mm"]]
            fixed = float(red["fixed_end_mm"])
            dt = float(red["dt_s"])
            Tmax = float(red["state_max_K"])
            if not all(math.isfinite(v) for v in [fixed, dt, Tmax] + edges):
                raise ValueError("fixed_end_mm, dt_s, state_max_K and edges_mm must be finite numbers")
        except (KeyError, TypeError, ValueError) as exc:
            raise ExportError("thermal.reduced: missing or invalid field %s" % exc)
        fmax_f = red.get("feed_max_mm_min")
        if not isinstance(fmax_f, (int, float)) or not fmax_f >= 0:
            raise ExportError("thermal.reduced.feed_max_mm_min is missing: the travel bound per step is needed")
        if not 1 <= M <= 32 or A.shape != (M, M) or B.shape != (M,) or len(edges) != M + 1:
            raise ExportError("thermal.reduced: segments=%d needs A %dx%d, B_K_per_mm %d, edges_mm %d (got %s, %s, %d)"
                              % (M, M, M, M, M + 1, A.shape, B.shape, len(edges)))
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B)) and Tmax > 0 and dt > 0):
            raise ExportError("thermal.reduced: A, B_K_per_mm must be finite, state_max_K and dt_s positive")
        if np.any(B < 0):
            raise ExportError("thermal.reduced.B_K_per_mm: negative heating coefficient")
        if edges[0] != 0 or any(b <= a for a, b in zip(edges, edges[1:])):
            raise ExportError("thermal.reduced.edges_mm must start at 0 and ascend")
        dt_ms = rnd(F(dt) * 1000)
        if abs(F(dt) * 1000 - dt_ms) > F(1, 10 ** 6) or dt_ms < 1:
            raise ExportError("thermal.reduced.dt_s=%r is not a whole number of milliseconds" % dt)
        fmax = math.ceil(fmax_f)
        if fmax * dt_ms >= PROD:
            raise ExportError("thermal.reduced.feed_max_mm_min x dt_s: travel per step too large for the table")
        edges_um = [rnd(F(e) * 1000) for e in edges]
        if any(b <= a for a, b in zip(edges_um, edges_um[1:])):
            raise ExportError("thermal.reduced.edges_mm: segments shorter than 1 um")
        fe = rnd(F(fixed) * 1000)
        if max(abs(m.pos_lo - fe), abs(m.pos_hi - fe)) + edges_um[-1] >= PROD:
            raise ExportError("thermal.reduced.fixed_end_mm / edges_mm: screw coordinates too large for the table")
        umax = -(-fmax * dt_ms // 60)
        air, c0, c1, d_air = self._screw_air(red, A, M)
        # the state is the heat response (in [0, state_max_K]) plus the air response, a convex combination of
        # air readings (A >= 0, c0, c1 >= 0, row sums of [A c0 c1] <= 1, 0 inside the air range): together
        # [a_min, a_max + state_max_K] (host/learning/screw/reduced.py)
        Tlo_K = F(d_air[0], 1000)
        Thi_K = F(Tmax) + F(d_air[1], 1000)
        Bu, rev = self._screw_effects(red, M)
        g0, gv, D = self._screw_speed_effects(red, A, M, umax)
        self.s = ReducedScrew(M=M, A=A, B=B, edges=edges, edges_um=edges_um, fixed=fixed, fe=fe, Tmax=Thi_K, Tlo=Tlo_K, umax=umax,
                              air=air, c0=c0, c1=c1, d_air=d_air, Bu=Bu, rev=rev, g0=g0, gv=gv, D=D)
        f.update(M=M, dt_ms=dt_ms, fixed_end=fe, fmax=fmax, edges=edges_um, umax=umax, air=air)
        alpha = m.alpha
        return abs(alpha) * max(Thi_K, -Tlo_K) * F(edges[-1]) * OU_PER_UM * 2  # x2: margin for state errors

    def _screw_effects(self, red: dict[str, Any], M: int) -> tuple[list[Fraction], Fraction]:
        """The effects' reduced forms (host/learning/screw/effects.py reduce): heat per mm of the step's total travel
        (K/mm, per segment, >= 0) and the reversal term (um); zeros for a document without them."""
        hu = red.get("travel_heat_K_per_mm")
        if hu is None:
            Bu = [F(0)] * M
        else:
            if not isinstance(hu, list) or len(hu) != M or not all(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0
                                                                  for v in hu):
                raise ExportError("thermal.reduced.travel_heat_K_per_mm must be %d finite non-negative numbers" % M)
            Bu = [F(float(v)) for v in hu]
        rev = red.get("reversal_um", 0.0)
        if not isinstance(rev, (int, float)) or not math.isfinite(rev) or abs(rev) > 1000:
            raise ExportError("thermal.reduced.reversal_um must be a finite number of um below 1000 (got %r)" % (rev,))
        return Bu, F(float(rev))

    def _screw_speed_effects(self, red: dict[str, Any], A: np.ndarray, M: int,
                             umax: int) -> tuple[Fraction | None, Fraction, list[Fraction]]:
        """The speed effects' reduced forms (format 5): the friction heat's factor g(U) = g0 + gv·U (gv per um; g0 None
        and gv 0 without speed_dependent_heat) and the extra convection weight D_i per um of the step's travel (moving_convection;
        zeros without it). Refuses a factor that turns negative on [0, umax] (no state bound) and D_i·umax > A_ii (the
        explicit step would be no convex combination: neither the state nor its error would stay bounded)."""
        g0_doc, gv_doc = red.get("heat_scale0"), red.get("heat_scale_per_mm")
        if g0_doc is None and gv_doc is None:
            g0, gv = None, F(0)
        else:
            g0, gv = _heat_scale(g0_doc, "heat_scale0"), _heat_scale(gv_doc, "heat_scale_per_mm") / 1000
            if g0 < 0 or g0 + gv * umax < 0:
                raise ExportError("thermal.reduced.heat_scale0/heat_scale_per_mm: the friction heat factor is negative on "
                                  "the travel range 0..%d um per step (speed_dependent_heat): no certified state bound" % umax)
        dd = red.get("convection_per_mm")
        if dd is None:
            D = [F(0)] * M
        else:
            if not isinstance(dd, list) or len(dd) != M or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0 for v in dd):
                raise ExportError("thermal.reduced.convection_per_mm must be %d finite non-negative numbers" % M)
            D = [F(float(v)) / 1000 for v in dd]
            for i in range(M):
                if D[i] * umax > F(float(A[i, i])):
                    raise ExportError("thermal.reduced.convection_per_mm[%d]: the extra loss per step at the top feed, %.4g, "
                                      "exceeds A[%d][%d] = %.4g (moving_convection): the explicit step is not stable"
                                      % (i, float(D[i] * umax), i, i, float(A[i, i])))
        return g0, gv, D

    def _screw_air(self, red: dict[str, Any], A: np.ndarray, M: int) -> tuple[int, list[Fraction], list[Fraction], IntInterval]:
        """(channel index or -1, c0, c1 as Fractions, air range (milli-K) over its reference)."""
        m = self.m
        name = red.get("air_sensor")
        if name is None:
            return -1, [F(0)] * M, [F(0)] * M, (0, 0)
        if name not in m.sensors:
            raise ExportError("thermal.reduced.air_sensor %r is not in sensors %r" % (name, m.sensors))
        try:
            c0 = [F(float(v)) for v in red["air_K0"]]
            c1 = [F(float(v)) for v in red["air_K1"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise ExportError("thermal.reduced: missing or invalid air weights %s" % exc)
        if len(c0) != M or len(c1) != M or not all(math.isfinite(v) and v >= 0 for v in c0 + c1):
            raise ExportError("thermal.reduced.air_K0/air_K1 must be %d finite non-negative numbers" % M)
        for i in range(M):
            if sum(F(float(max(a, 0.0))) for a in A[i]) + c0[i] + c1[i] > 1 + F(1, 10 ** 9):
                raise ExportError("thermal.reduced row %d: A + air weights sum above 1 (the air would be amplified)" % i)
        i = m.sensors.index(name)
        d_air = (m.d_lo[i], m.d_hi[i])
        if not d_air[0] <= 0 <= d_air[1]:
            raise ExportError("thermal.reduced.air_ref_C lies outside the air sensor's envelope %r" % (name,))
        return i, c0, c1, d_air

    def screw_state(self, fo: int) -> tuple[IntInterval, Interval]:
        """Recurrence, state error certificate, cum/segslope; returns (seg(p) interval, seg(p) error interval).

        Tries 2..5 state limbs (more limbs: finer C = A - I, more multiplications per step) and keeps
        the one with the smallest certified offset error."""
        best = None
        last = None
        for ns in (2, 3, 4, 5):
            try:
                sub = Planner(self.m)
                sub.f = dict(self.f)
                sub.s = self.s
                out = sub._screw_state(fo, ns)
            except ExportError as exc:
                last = exc
                continue
            e = iv_abs(out[1])
            if best is None or e < best[0] * F(99, 100):  # fewer limbs unless clearly better
                best = (e, sub, out)
        if best is None:
            assert last is not None  # every limb count was refused, each with its ExportError: last holds one
            raise last
        _, sub, out = best
        self.f.update(sub.f)
        _merge(self.rec, sub.rec)
        self.terms += sub.terms
        self.state_cert = sub.state_cert
        self.sobs_cert = sub.sobs_cert
        return out

    def _screw_state(self, fo: int, ns: int) -> tuple[IntInterval, Interval]:
        m, f, rec, s = self.m, self.f, self.rec, self.s
        M, A = s["M"], s["A"]
        Tmax, Tlo = s["Tmax"], s["Tlo"]
        Tabs = max(Tmax, -Tlo)
        ft = frac_bits(Tabs, ACC, cap=30)
        Tq = math.ceil(Tmax * p2(ft))
        Tlq = math.floor(Tlo * p2(ft))
        nbits = max(Tq.bit_length(), (-Tlq).bit_length())
        Ls = max(1, -(-nbits // ns))
        if Ls * (ns - 1) >= nbits and ns > 2:
            raise ExportError("state limbs: %d limbs are more than the state needs" % ns)
        T_iv = (Tlq, Tq)
        TA = max(Tq, -Tlq)
        lms = limb_max(T_iv, Ls, ns)
        limb_ivs = limbs(T_iv, Ls, ns)
        rec.note(ACC_LIMB, limb_ivs[-1][0], limb_ivs[-1][1], "state")
        Cx = [[F(float(A[i, j])) - (1 if i == j else 0) for j in range(M)] for i in range(M)]
        rowsum = max(sum(abs(c) for c in row) for row in Cx)
        fc = frac_bits(rowsum * lms, PROD, cap=62)
        while True:
            Cq = [[rnd(c * p2(fc)) for c in row] for row in Cx]
            if max(sum(abs(c) for c in row) for row in Cq) * lms <= PROD:
                break
            fc -= 1
        umax = s["umax"]
        g0, gv, D = s["g0"], s["gv"], s["D"]
        # the step's total travel U: exact with position reports (a sum of integers); in the feed/range mode the firmware
        # takes U = F, the feed's travel per step floored to 1 um (the spread's fractions sum to 1), not the sum of the
        # segments' floored shares
        dU = (F(-1), F(0))
        gmax = F(1) if g0 is None else g0 + max(gv, F(0)) * umax
        # the effective travel u·g(U) (speed_dependent_heat) as the limb-wise interval products bound it: a limb split
        # of [0, umax] sums to at most 2·umax, and g's own product the same
        ueff = umax if g0 is None else math.ceil(2 * umax * (g0 + 2 * max(gv, F(0)) * umax)) + 64
        nu = 2
        Lu = max(1, -(-ueff.bit_length() // nu))
        U_iv = (0, umax)
        lmu = limb_max((0, ueff), Lu, nu)
        # guard bits: the row sum |C T| + B u + W a + D U (T - a) (state units) times 2**gs stays below ACC
        Bmax = max(F(float(b)) * gmax + bu for b, bu in zip(s["B"], s["Bu"])) / 1000 * p2(ft) * umax
        d_air = s["d_air"]
        Dabs = max(-d_air[0], d_air[1])
        Wmax = max(c0 + c1 for c0, c1 in zip(s["c0"], s["c1"])) / 1000 * p2(ft) * Dabs
        emax = max(D) * umax  # the largest extra convection weight of a step (<= A_ii, checked)
        gs = max(0, min(20, frac_bits(rowsum * TA + Bmax + Wmax + emax * (Tq - Tlq) + 1, ACC)))
        lmd = limb_max(d_air, f["Lt"], f["nt"])
        # the start state (Evaluator.settle) and the air in state units the convection term reads: Ka * a ~ a * 2**ft / 1000
        if s["air"] >= 0:
            Ka, shKa = fit_coef(p2(ft) / 1000, lmd, 0)
            a0_iv, k = rec.mul(ACC_AMUL, (Ka, Ka), d_air, f["Lt"], f["nt"], shKa, "air start state")
            e0 = iv_abs(iv_add(iv_mul(_c(F(Ka) / p2(shKa) - p2(ft) / 1000), (F(d_air[0]), F(d_air[1]))), floor_err(k)))
        else:
            Ka, shKa, e0 = 0, 0, F(0)
            a0_iv = (0, 0)
        e_start = max(e0, self.screw_observer(ft, Tlq, Tq, Ka, shKa, a0_iv, e0))
        # speed_dependent_heat: g = g0 + Gv*U at 2**-fg (below 2**20, so g x travel limbs of 9 bits stay small ints)
        if g0 is None:
            fg, g0q, Gvq, shGv, Lgu, ngu = 0, 0, 0, 0, 1, 1
            err_g = ZERO
        else:
            fg = max(1, min(30, frac_bits(gmax + 1, 1 << 20)))
            g0q = rnd(g0 * p2(fg))
            Gvq, shGv = fit_coef(gv, limb_max(U_iv, Lu, nu), fg)
            gres, kg = rec.mul(ACC_GMUL, (Gvq, Gvq), U_iv, Lu, nu, shGv, "thermal.reduced.heat_scale_per_mm")
            g_iv = (g0q + gres[0], g0q + gres[1])
            rec.note(ACC_GMUL + 1, g_iv[0], g_iv[1], "thermal.reduced.heat_scale_per_mm")
            # g's error (2**-fg units): the quantisation of g0 and of Gv (times U >= 0) and Gv*U's floors
            err_g = iv_add(_c(F(g0q) - g0 * p2(fg)), iv_mul(_c(F(Gvq) / p2(shGv) - gv * p2(fg)), (F(0), F(umax))), floor_err(kg))
            # the limb-wise interval loses the limbs' correlation: g is the exact factor on [0, umax] plus its error
            g_exact = (min(g0, g0 + gv * umax) * p2(fg), max(g0, g0 + gv * umax) * p2(fg))
            g_iv = _meet(g_iv, int_iv(g_exact, err_g))
            gabs = max(abs(g_iv[0]), abs(g_iv[1]), 1)
            Lgu = narrow_width(gabs)
            ngu = top_limbs_needed(U_iv, Lgu, gabs)
            if ngu is None:
                raise ExportError("thermal.reduced.heat_scale_per_mm: the effective travel cannot be formed in small-int limbs")
            ue_iv, kgu = rec.mul(ACC_UGMUL, g_iv, U_iv, Lgu, ngu, fg, "speed heat: travel x g")
            if max(-ue_iv[0], ue_iv[1]) > ueff:
                raise ExportError("thermal.reduced.heat_scale_per_mm: the effective travel %r leaves its range" % (ue_iv,))
            # effective travel error (um): u * err_g / 2**fg and the floors
            # the feed/range mode's travel rounding moves U (so g) too
            err_ue = iv_add(iv_mul((F(0), F(umax)), iv_scale(err_g, 1 / p2(fg))), floor_err(kgu),
                            _hull(ZERO, iv_mul((F(0), F(umax)), iv_scale(dU, gv))))
        ue_range = (F(0), F(umax) * gmax)
        # moving_convection: eps_i = D_i*U at 2**-fe (below 2**24: its floors times the state-minus-air range are the
        # term's main error), then eps_i x (T_i - a0) with y in Ly-bit limbs (5 bits: 6 limbs of a 2**29 range)
        # y = T_i - a0: the exact state is its heat response (in [0, state_max_K]) plus a convex combination of the air's
        # readings, which lie within the air envelope's span of a0; the integer state is within the certified state error
        # of it (checked below against the 1 K margin)
        span = F(m.env_hi[s["air"]] - m.env_lo[s["air"]], 1000) if s["air"] >= 0 else F(0)
        heat_K = F(float(m.red["state_max_K"]))
        y_iv = (math.floor(-(span + 1) * p2(ft)), math.ceil((heat_K + span + 1) * p2(ft)))
        if emax:
            fe = max(1, min(30, frac_bits(emax, 1 << EPS_BITS)))
            Ly = narrow_width(1 << EPS_BITS)
            ny = top_limbs_needed(y_iv, Ly, 1 << EPS_BITS)
            if ny is None:
                raise ExportError("thermal.reduced.convection_per_mm: state x weight does not fit small-int limbs")
        else:
            fe, Ly, ny = 0, 1, 1
        Dq, shD = [], []
        W0q, shW0, W1q, shW1 = [], [], [], []
        Bq, shB, rS = [], [], []
        Buq, shBu = [], []
        rho = []
        parts = []  # per row: (C quantisation, B quantisation + feed rounding), state units per step
        feed_du = (-(F(umax) / p2(FEED_W_BITS) + 4), F(0))  # feed/range mode travel error per segment (um)
        for i in range(M):
            name = "thermal.reduced.A[%d]" % i
            acc = (0, 0)
            err = ZERO  # guard units: 2**-(ft + gs) K
            sh = fc - gs
            for k in range(ns):
                r = (0, 0)
                for j in range(M):
                    c = Cq[i][j]
                    lo, hi = limb_ivs[k]
                    p = (min(c * lo, c * hi), max(c * lo, c * hi))
                    rec.note(ACC_ROWMUL, p[0], p[1], name)
                    r = iv_add(r, p)
                    rec.note(ACC_ROWMUL, r[0], r[1], name)
                if sh > 0:
                    acc = iv_add(acc, (r[0] >> sh, r[1] >> sh))
                    err = iv_add(err, floor_err(1))
                else:
                    acc = iv_add(acc, (r[0] << -sh, r[1] << -sh))
                rec.note(ACC_ROW, acc[0], acc[1], name)
                sh -= Ls
            errC = ZERO
            for j in range(M):
                dc = F(Cq[i][j]) / p2(fc) - Cx[i][j]
                errC = iv_add(errC, iv_mul(_c(dc * p2(gs)), (F(Tlq), F(Tq))))
            err = iv_add(err, errC)
            q, sb = fit_coef(F(float(s["B"][i])) / 1000, lmu, ft + gs)
            Bq.append(q)
            shB.append(sb)
            bq = F(q) / p2(sb)
            db = bq - F(float(s["B"][i])) / 1000 * p2(ft + gs)
            if g0 is None:
                res, k = rec.mul(ACC_BMUL, (q, q), U_iv, Lu, nu, sb, "thermal.reduced.B_K_per_mm[%d]" % i)
                errB = iv_add(iv_mul(_c(db), (F(0), F(umax))), _hull(ZERO, iv_scale(feed_du, bq)))
            else:
                # on the effective travel u*g: B's quantisation over its range, the travel's error times B, and the
                # feed/range mode's travel rounding times g
                res, k = rec.mul(ACC_BMUL, (q, q), (min(0, ue_iv[0]), ue_iv[1]), Lu, nu, sb, "thermal.reduced.B_K_per_mm[%d]" % i)
                errB = iv_add(iv_mul(_c(db), ue_range), iv_scale(err_ue, bq), _hull(ZERO, iv_scale(feed_du, bq * gmax)))
            err = iv_add(err, errB, floor_err(k))
            acc = iv_add(acc, res)
            # the effects' heat per mm of the step's total travel U = sum u (clamped to umax, as u is); in the
            # feed/range mode U carries every segment's travel rounding
            if s["Bu"][i]:
                q, sb = fit_coef(s["Bu"][i] / 1000, lmu, ft + gs)
                res, k = rec.mul(ACC_BMUL, (q, q), U_iv, Lu, nu, sb, "thermal.reduced.travel_heat_K_per_mm[%d]" % i)
                bq = F(q) / p2(sb)
                dbu = bq - s["Bu"][i] / 1000 * p2(ft + gs)
                # the quantisation (one-sided in U >= 0), the floors and the feed/range mode's travel rounding widen
                # the interval but stay out of the rounding bias below, so an idle screw stays where it is
                errBu = iv_add(iv_mul(_c(dbu), (F(0), F(umax))), floor_err(k), _hull(ZERO, iv_scale(iv_scale(feed_du, M), bq)))
                errB = iv_add(errB, errBu)
                acc = iv_add(acc, res)
            else:
                q, sb = 0, 0
            Buq.append(q)
            shBu.append(sb)
            errD = ZERO
            if s["D"][i]:
                # - eps_i * (T_i - a0): eps's quantisation and floors times y, the floors of the product (they lower the
                # loss), and eps times the air's start-state error; the state's own error enters the recursion through
                # A - diag(eps), |A - diag(eps)| <= |A| as eps <= A_ii (checked), so the supersolution below covers it
                q, sd = fit_coef(s["D"][i], lmu, fe)
                Dq.append(q)
                shD.append(sd)
                e_iv, k1 = rec.mul(ACC_EMUL, (q, q), U_iv, Lu, nu, sd, "thermal.reduced.convection_per_mm[%d]" % i)
                if e_iv[1] > (1 << EPS_BITS) or e_iv[0] < 0:
                    raise ExportError("thermal.reduced.convection_per_mm[%d]: the weight leaves its %d bits" % (i, EPS_BITS))
                err_e = iv_add(iv_mul(_c(F(q) / p2(sd) - s["D"][i] * p2(fe)), (F(0), F(umax))), floor_err(k1),
                               _hull(ZERO, iv_scale(dU, s["D"][i] * p2(fe))))
                rec.note(ACC_CONVY, y_iv[0], y_iv[1], "thermal.reduced.convection_per_mm[%d]" % i)
                loss, k2 = rec.mul(ACC_LMUL, e_iv, y_iv, Ly, ny, fe - gs, "thermal.reduced.convection_per_mm[%d]" % i)
                acc = iv_add(acc, (-loss[1], -loss[0]))
                err_l = iv_add(iv_scale(iv_mul(err_e, (F(y_iv[0]), F(y_iv[1]))), p2(gs - fe)), floor_err(k2))
                eps_max = s["D"][i] * umax
                errD = iv_add((-err_l[1], -err_l[0]), iv_scale((-e0, e0), eps_max * p2(gs)))
                errB = iv_add(errB, errD)
            else:
                Dq.append(0)
                shD.append(0)
            # air at the step's start and end (milli-K over the reference), weights c/1000 K per mK
            errW = ZERO
            for c, qs, shs in ((s["c0"][i], W0q, shW0), (s["c1"][i], W1q, shW1)):
                q, sw = fit_coef(c / 1000, lmd, ft + gs)
                qs.append(q)
                shs.append(sw)
                res, k = rec.mul(ACC_AMUL, (q, q), d_air, f["Lt"], f["nt"], sw, "thermal.reduced.air_K[%d]" % i)
                acc = iv_add(acc, res)
                errW = iv_add(errW, iv_mul(_c(F(q) / p2(sw) - c / 1000 * p2(ft + gs)), (F(d_air[0]), F(d_air[1]))), floor_err(k))
            err = iv_add(err, errW)
            parts.append((iv_abs(errC) / p2(gs), (iv_abs(errB) + iv_abs(errW)) / p2(gs)))
            err = iv_add(err, errD)  # (centred with the rest: the term is 0 when idle, and so symmetric in y)
            bias, _ = _round_out(err, gs)
            if s["Bu"][i]:
                err = iv_add(err, errBu)
            bias, err_state = _round_out(err, gs, bias)  # v = T + (acc + rS) >> gs
            rS.append(bias)
            acc = (acc[0] + bias, acc[1] + bias)
            rec.note(ACC_ROW, acc[0], acc[1], name)
            rec.note(ACC_STATE, Tlq + (acc[0] >> gs), Tq + (acc[1] >> gs), name)
            rho.append(max(abs(err_state[0]), abs(err_state[1])))
        # travel accumulators and the feed fallback
        maxlen = max(b - a for a, b in zip(s["edges_um"], s["edges_um"][1:]))
        rec.note(ACC_TRAVEL, 0, umax + max(maxlen, umax), "travel")
        rec.mul(ACC_FEEDMUL, (0, 1 << FEED_W_BITS), (0, umax), FEED_LIMB, 3, FEED_W_BITS, "travel")
        rec.note(ACC_STATE, Tlq, Tq, "air start state")
        # state error: v >= |A| v + rho, verified exactly; a start error e0 adds e0 to every component
        # (|A| has row sums <= 1, so v + e0 is again a supersolution and bounds the error from the start)
        v = _supersolution(A, rho)
        if v is None:
            raise ExportError("thermal.reduced.A: the recurrence is not contracting (|A| has spectral radius >= 1); "
                              "the integer state error cannot be bounded")
        if e_start:
            AF = [[F(float(abs(a))) for a in row] for row in np.asarray(A, dtype=float)]
            if any(sum(row) > 1 for row in AF):
                raise ExportError("thermal.reduced.A: a row sum above 1, the start state's error cannot be bounded")
            v = [x + e_start for x in v]
        if emax and max(v) + e0 >= p2(ft):
            raise ExportError("thermal.reduced.convection_per_mm: the state error bound %.3g K exceeds the 1 K margin of the "
                              "state minus the air" % float((max(v) + e0) / p2(ft)))
        self.state_cert = {"rho_state_units": [float(r) for r in rho], "v_state_units": [float(x) for x in v], "ft": ft,
                           "start_error_state_units": float(e_start)}
        f.update(ft=ft, Tmax=Tq, Tlo=Tlq, Ls=Ls, ns=ns, fc=fc, gs=gs, C=[c for row in Cq for c in row], Lu=Lu, nu=nu, B=Bq,
                 shB=shB, rS=rS, W0=W0q, shW0=shW0, W1=W1q, shW1=shW1, Ka=Ka, shKa=shKa, Bu=Buq, shBu=shBu,
                 fg=fg, g0=g0q, Gv=Gvq, shGv=shGv, Lgu=Lgu, ngu=ngu, D=Dq, shD=shD, fe=fe, Ly=Ly, ny=ny)
        # informational split of the certified state error by source: output weight of a unit residual in row i
        W = np.linalg.inv(np.eye(M) - np.abs(np.asarray(A, dtype=float)))
        wout = [float(abs(m.alpha) * (F(s["edges"][j + 1]) - F(s["edges"][j])) * OU_PER_UM) / 2.0 ** ft for j in range(M)]
        gain = [sum(wout[j] * W[j, i] for j in range(M)) for i in range(M)]
        for i in range(M):
            big = max(abs(c) for c in Cq[i])
            rec.note(-1, -big, big, "thermal.reduced.A[%d]" % i)
            self.term("thermal.reduced.A[%d]" % i, fc, F(gain[i] * float(parts[i][0])))
            self.term("thermal.reduced.B_K_per_mm[%d]" % i, ft + gs + shB[i], F(gain[i] * float(parts[i][1])),
                      key="thermal.reduced.B_K_per_mm[%d]" % i)
        self.term("state rounding (2^-%d K per step)" % ft, ft,
                  F(sum(gain[i] * max(0.0, float(rho[i]) - float(parts[i][0]) - float(parts[i][1])) for i in range(M))), key="state")
        # elongation profile: cum (scale 2**fo) and segment slopes (scale 2**fh)
        alpha = m.alpha
        edges = s["edges"]
        G2, shG2 = [], []
        cum = (0, 0)
        err_cum = [ZERO]
        cum_ivs = [(0, 0)]
        ecum = ZERO
        for i in range(M):
            ln = F(edges[i + 1]) - F(edges[i])
            val = alpha * ln * OU_PER_UM
            q, sh = fit_coef(val, lms, fo - ft)
            G2.append(q)
            shG2.append(sh)
            res, k = rec.mul(ACC_CUMMUL, (q, q), T_iv, Ls, ns, sh, "thermal.reduced.alpha x edges[%d]" % i)
            cum = iv_add(cum, res)
            rec.note(ACC_CUM, cum[0], cum[1], "thermal.reduced.alpha x edges[%d]" % i)
            gq = F(q) / p2(sh)
            dq = gq - val * p2(fo - ft)
            ecum = iv_add(ecum, iv_mul(_c(dq), (F(Tlq), F(Tq))), floor_err(k), iv_scale((-v[i], v[i]), abs(gq)))
            err_cum.append(ecum)
            cum_ivs.append(cum)
            self.term("thermal.reduced.alpha x edges[%d]" % i, fo - ft + sh, abs(dq) * TA / p2(fo))
        hval = alpha * F(OU_PER_UM, 1000)  # OU per um per K
        fh = frac_bits(abs(hval) * (Tabs + 1), ACC)
        H, shH = fit_coef(hval, lms, fh - ft)
        hq = F(H) / p2(shH)
        seg_ivs, err_ss = [], []
        for i in range(M):
            res, k = rec.mul(ACC_HMUL, (H, H), T_iv, Ls, ns, shH, "thermal.reduced.alpha_um_per_mm_per_K")
            seg_ivs.append(res)
            err_ss.append(iv_add(iv_mul(_c(hq - hval * p2(fh - ft)), (F(Tlq), F(Tq))), floor_err(k),
                                 iv_scale((-v[i], v[i]), abs(hq))))
        eu = s["edges_um"]
        LEN = max(b - a for a, b in zip(eu, eu[1:]))
        self.term("thermal.reduced.alpha_um_per_mm_per_K", fh - ft + shH, abs(hq - hval * p2(fh - ft)) * TA * LEN / p2(fh))
        Lx = narrow_width(LEN)
        ss_all = _hull(*[(F(a), F(b)) for a, b in seg_ivs])
        ss_int = (int(ss_all[0]), int(ss_all[1]))
        nx = top_limbs_needed(ss_int, Lx, LEN)
        if nx is None:
            raise ExportError("thermal.reduced.alpha_um_per_mm_per_K: segment slope x length does not fit small-int limbs")
        shX = fh - fo
        rec.note(ACC_XL, 0, LEN, "position")
        segs, segerr = [(0, 0)], [ZERO]
        for kk in range(M):
            res, k = rec.mul(ACC_SEGMUL, (0, eu[kk + 1] - eu[kk]), seg_ivs[kk], Lx, nx, shX, "segment elongation")
            iv = iv_add(cum_ivs[kk], res)
            rec.note(ACC_CUM, iv[0], iv[1], "segment elongation")
            segs.append(iv)
            segerr.append(iv_add(err_cum[kk], iv_scale(iv_mul((F(0), F(eu[kk + 1] - eu[kk])), err_ss[kk]), 1 / p2(shX)),
                                 floor_err(k)))
        segs.append(cum_ivs[M])
        segerr.append(err_cum[M])
        # edges and fixed end rounded to whole um (geometry, not arithmetic). E(x) = alpha * integral of the
        # piecewise-constant profile T(s) in [0, Tmax] up to x: moving x by d changes it by <= alpha*Tmax*|d|;
        # the integer profile differs from the exact one only where the segment containing x starts (cum uses
        # the exact lengths), which moves by <= 2 max|d edge|.
        dfe = abs(F(s["fe"]) - F(s["fixed"]) * 1000)
        dedge = max(abs(F(a) - F(b) * 1000) for a, b in zip(eu, edges))
        geo_um = abs(alpha) * Tabs * (dfe + 2 * dedge) / 1000
        e_geo = geo_um * OU_PER_UM * p2(fo)
        seg_iv = _hull(*segs)
        err_seg = iv_add(_hull(*segerr), (-e_geo, e_geo))
        self.term("edges/fixed end rounded to 1 um", 0, geo_um * OU_PER_UM)
        f.update(G2=G2, shG2=shG2, H=H, shH=shH, fh=fh, Lx=Lx, nx=nx, shX=shX)
        return seg_iv, err_seg

    def screw_observer(self, ft: int, Tlq: int, Tq: int, Ka: int, shKa: int, a0_iv: IntInterval, e_air: Num) -> Num:
        """Quantise and certify the screw observer (Evaluator.estimate; issue 21); returns the largest |start error|
        (state units) of a segment against the host's estimate T_i = a + G_i r (host/learning/screw/observer.py), 0
        without an observer.

        Segment i: v = a + mul(Gn[i], r, Lr, nr, shGn[i]) + rN[i], clamped to [Tlo, Tmax]; a is settle()'s air state
        (error ``e_air``, plus the air reference's rounding under fixed references), r the nut's integer rise over sensor
        sr, clamped to +-Rn. Against the host's a + G_i (r + c) (c: the integer references minus the observer's exact
        ones, 0 when latched) the error is a's, G's quantisation times r, the floors and rN - G c (rN centres the
        floors). Rn = 2 TA / max G: the estimate stays inside 3 TA < 2**30 and where the clamp acts the host's estimate
        is beyond the state bounds anyway. The clamp to [Tlo, Tmax] only removes error when the host's estimate lies
        inside them (a projection); the report says whether it can leave them over the envelope."""
        m, f, rec, s = self.m, self.f, self.rec, self.s
        M = s["M"]
        obs = getattr(m, "screw_obs", None)
        f.update(obs=0, settle_s=0, sn=-1, sr=-1, Rn=0, Lr=1, nr=1, Gn=[0] * M, shGn=[0] * M, rN=[0] * M)
        self.sobs_cert = None
        if obs is None:
            return F(0)
        i_n, i_r = m.sensors.index(obs["sensor"]), m.sensors.index(obs["air_sensor"])
        r_iv = (m.d_lo[i_n] - m.d_hi[i_r], m.d_hi[i_n] - m.d_lo[i_r])
        TA = max(Tq, -Tlq)
        Gs = [g * p2(ft) / 1000 for g in obs["gains"]]  # state units per milli-K
        gmax = max(abs(g) for g in Gs)
        R = max(-r_iv[0], r_iv[1])
        if gmax:
            R = min(R, math.floor(2 * TA / gmax))
        rc = (max(r_iv[0], -R), min(r_iv[1], R))
        nr = 2
        Lr = max(1, -(-max(R, 1).bit_length() // nr))
        exact = obs["reference_mC"]
        c = F(0)
        if exact is not None:
            c = (m.ref[i_n] - exact[obs["sensor"]]) - (m.ref[i_r] - exact[obs["air_sensor"]])
        # the air's state against the host's a: settle()'s arithmetic and, under fixed references, the table's integer
        # air reference against thermal.reduced.air_ref_C
        err_a = (-F(e_air), F(e_air))
        if s["air"] >= 0 and not m.ref_mode:
            da = F(m.ref[s["air"]]) - F(float(m.red["air_ref_C"])) * 1000
            err_a = iv_add(err_a, _c(-da * p2(ft) / 1000))
        a_iv = (max(a0_iv[0], Tlq), min(a0_iv[1], Tq)) if s["air"] >= 0 else (0, 0)
        Gn, shGn, rN, segs = [], [], [], []
        worst = F(0)
        um = F(0)
        clamped = False
        edges = s["edges"]
        for i in range(M):
            name = "thermal.observer.gains_K_per_K[%d]" % i
            q, sh = fit_coef(Gs[i], limb_max(rc, Lr, nr), 0) if Gs[i] else (0, 0)
            res, k = rec.mul(ACC_NMUL, (q, q), rc, Lr, nr, sh, name) if q else ((0, 0), 0)
            bias = rnd(Gs[i] * c + F(k, 2))
            err = iv_add(err_a, iv_mul(_c(F(q) / p2(sh) - Gs[i]), (F(rc[0]), F(rc[1]))), floor_err(k), _c(bias - Gs[i] * c))
            tot = iv_add(a_iv, res, (bias, bias))
            rec.note(ACC_NSUM, tot[0], tot[1], name)
            est = iv_add((F(a0_iv[0]), F(a0_iv[1])), iv_mul(_c(Gs[i]), (F(r_iv[0]), F(r_iv[1]))))
            clamped = clamped or est[0] < Tlq or est[1] > Tq
            Gn.append(q)
            shGn.append(sh)
            rN.append(bias)
            e = iv_abs(err)
            worst = max(worst, e)
            # the offset: segment i's state error over its length, alpha x length x error (largest at the far end)
            um += abs(m.alpha) * (F(edges[i + 1]) - F(edges[i])) * e / p2(ft)
            segs.append({"gain_K_per_K": float(obs["gains"][i]), "start_error_K": float(e / p2(ft))})
        f.update(obs=1, settle_s=obs["settle_s"], sn=i_n, sr=i_r, Rn=R, Lr=Lr, nr=nr, Gn=Gn, shGn=shGn, rN=rN)
        self.sobs_cert = {"sensor": obs["sensor"], "air_sensor": obs["air_sensor"], "settle_s": obs["settle_s"],
                          "rise_clamp_mK": R, "segments": segs, "start_error_K": float(worst / p2(ft)),
                          "start_error_um": float(um), "estimate_clamped_in_envelope": bool(clamped)}
        return worst

    def screw_chord(self, seg_iv: IntInterval, err_seg: Interval, fo: int, fK: int) -> tuple[IntInterval, Interval]:
        """slope += KC * (seg(pos_hi) - seg(pos_lo)): the chord of the segment elongation over the envelope."""
        m, f, rec = self.m, self.f, self.rec
        de = (seg_iv[0] - seg_iv[1], seg_iv[1] - seg_iv[0])
        rec.note(ACC_DE, de[0], de[1], "slope chord")
        span = m.pos_hi - m.pos_lo
        nc = 3
        Lc = max(1, -(-max(abs(de[0]), abs(de[1]), 1).bit_length() // nc))
        lmc = limb_max(de, Lc, nc)
        if span == 0:
            KC, shC = 0, 0
        else:
            KC, shC = fit_coef(F(SLOPE_PER_OU_PER_UM, span), lmc, fK - fo)
        f.update(KC=KC, Lc=Lc, nc=nc, shC=shC)
        res, k = rec.mul(ACC_CMUL, (KC, KC), de, Lc, nc, shC, "KC (chord slope)")
        kq = F(KC) / p2(shC)
        target = F(SLOPE_PER_OU_PER_UM, span) * p2(fK - fo) if span else F(0)
        err = iv_add(iv_scale((F(de[0]), F(de[1])), kq - target),
                     iv_scale(iv_add(err_seg, (-err_seg[1], -err_seg[0])), kq), floor_err(k))
        self.term("KC (chord slope)", fK - fo + shC, 0)
        return res, err


class _Retry(Exception):
    pass


def _heat_scale(v: object, name: str) -> Fraction:
    """thermal.reduced.<name> (speed_dependent_heat's heat_scale0 or heat_scale_per_mm), a finite number of
    magnitude <= 1000, exactly."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or abs(v) > 1000:
        raise ExportError("thermal.reduced.%s must be a finite number (got %r)" % (name, v))
    return F(float(v))


def _merge(dst: Recorder, src: Recorder) -> None:
    for acc_id, (lo, hi) in src.accs.items():
        dst.note(acc_id, lo, hi, "_merge")
    for k, v in src.peaks.items():
        dst.peaks[k] = max(dst.peaks.get(k, 0), v)
    dst.peaks.pop("_merge", None)


def _largest(m: Model, PM: int = 1, seg_bound: Num = 0) -> str:
    """Name of the term with the largest contribution to the output range (for refusals)."""
    cands = [(abs(m.b0) * PM, "thermal intercept")]
    cands += [(abs(b) * max(abs(lo), abs(hi)) * PM, n) for b, lo, hi, n in zip(m.b, m.d_lo, m.d_hi, m.b_names)]
    if not m.direct:
        cands += [(abs(g) * F(PM) ** j, "geometric.coefficients_um[%d]" % j) for j, g in enumerate(m.g)]
        cands.append((F(seg_bound), "thermal.reduced (segment elongation)"))
    return max(cands, key=lambda c: c[0])[1]


def _supersolution(A: np.ndarray, rho: Sequence[Num]) -> list[Fraction] | None:
    """v >= 0 with v >= |A| v + rho (exact check), or None."""
    Aa = np.abs(np.asarray(A, dtype=float))
    M = Aa.shape[0]
    r = np.array([float(x) for x in rho])
    try:
        v0 = np.linalg.solve(np.eye(M) - Aa, r)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(v0)) or np.any(v0 < 0):
        return None
    AF = [[F(float(Aa[i, j])) for j in range(M)] for i in range(M)]
    for inflate in (1e-9, 1e-6, 1e-3, 1e-1):
        v = [F(float(x) * (1 + inflate)) + F(1, 10 ** 6) for x in v0]
        if all(v[i] >= sum(AF[i][j] * v[j] for j in range(M)) + rho[i] for i in range(M)):
            return v
    return None


def _mag(iv: IntInterval) -> int:
    """The table's certified output bound: the largest |value| of an integer interval."""
    return int(max(abs(iv[0]), abs(iv[1])))
