"""The model document (docs/model-format.md) read into exact numbers in table units (docs/table-format.md).

``Model(doc)`` checks every field the exporter uses and names the bad one (ExportError); models_export.plan
quantises and certifies what it holds with models_export.certify's interval arithmetic. The document's hash is
models_export.document's job.
"""

from __future__ import annotations

from collections.abc import Mapping
from fractions import Fraction
from typing import Any, TypedDict
from typing import TYPE_CHECKING
import math
from fractions import Fraction as F

from models_export.certify import (
    ACC, OU_PER_UM, ExportError, Recorder, frac_bits, iv_add, iv_mul, narrow_width, p2, rnd, top_limbs_needed,
)
from firmware.table import SETTLE_NEVER  # pyright: ignore[reportAttributeAccessIssue]
from firmware.wire import MAX_SUPPLIED
from models_export.document import FORMAT

if TYPE_CHECKING:
    from models_export.certify import IntInterval, Interval, Num

# document kinds predict reads but no table kind of the firmware evaluates, and why (docs/model-format.md)
NOT_EXPORTABLE = {
    "ppr": "its ridge functions are natural cubic splines of projections of the rises, which no firmware table kind "
           "evaluates (a table holds fixed coefficients of poly_slope, linear_direct, screw or dynamic form); predict "
           "reads it, and for the board fit a method that exports (mlr, pcr, stepwise, cv-subset, dynamic, mr-poly, screw)",
}

# the document kinds a table evaluates -> that table's kind (certify.LIMITS_UM): mr_poly is written as a dynamic table
# (mr_poly_as_dynamic); a table kind such as screw_reduced is not a document's
TABLE_KINDS = {"poly_slope": "poly_slope", "linear_direct": "linear_direct", "screw": "screw_reduced", "dynamic": "dynamic",
               "mr_poly": "dynamic"}

# dynamic: the signal a filter reads -> firmware source code (>= 0: a sensor's index)
START = "start"  # the raw-error reference of docs/data-format.md (the exporter sees documents, not runs)
DYN_SOURCES = {"spindle_krpm": -1, "spindle_krpm2": -2, "feed_m_min": -3}
# "T<e>:<sensor>" (e = 2..4): the rise to the power e, source -4 - 3*i - (e - 2) (firmware Evaluator._inputs)
POWER_PREFIXES = {"T2:": 2, "T3:": 3, "T4:": 4}


def power_chain(rec: Recorder, x_iv: IntInterval, e: int, L: int, n: int, sh2: int, sh: int, name: str,
                acc: int) -> tuple[IntInterval, Interval, list[IntInterval]]:
    """Integer interval and error interval of the firmware's power x**e / 2**(sh2 + sh*(e - 2)) of an exact integer
    rise x, formed one floored factor at a time (Evaluator._inputs), recorded on ``rec`` as accumulator ``acc``;
    also the interval of every left factor (for the limb bound)."""
    v, err, cs = x_iv, (F(0), F(0)), [x_iv]
    for step in range(e - 1):
        s = sh2 if step == 0 else sh
        res, k = rec.mul(acc, v, x_iv, L, n, s, name)
        # floor-ish(v*x/2**s) = v*x/2**s + (-k, 0]; v = exact + err, so the error carries err*x/2**s
        err = iv_add(iv_mul(err, (F(x_iv[0]) / p2(s), F(x_iv[1]) / p2(s))), (F(-k), F(0)))
        v = res
        cs.append(v)
    return v, err, cs


def mr_poly_as_dynamic(doc: dict[str, Any]) -> dict[str, Any]:
    """An ``mr_poly`` document (S004's Eq. 12, host/learning/empirical/mrpoly.py) as the ``dynamic`` table that evaluates it:
    every filter has tau = 0 (its input passes through) and reads the nut rise, its powers, or the base rise."""
    th = _obj(doc.get("thermal"), "thermal")
    nut, base = th.get("nut_sensor"), th.get("base_sensor")
    if list(doc.get("sensors") or []) != [nut, base]:
        raise ExportError("mr_poly: sensors must be [thermal.nut_sensor, thermal.base_sensor], found %r" % (doc.get("sensors"),))
    # sensors equal to [nut, base] can still be no names (e.g. [null, null] with both fields null)
    nut = _sensor_name(nut, "mr_poly: thermal.nut_sensor")
    base = _sensor_name(base, "mr_poly: thermal.base_sensor")
    a = th.get("nut_coefficients")
    if not isinstance(a, list) or not 1 <= len(a) <= 4:
        raise ExportError("thermal.nut_coefficients must list 1..4 numbers (a_1..a_m), found %r" % (a,))
    terms = [{"signal": ("T:" if j == 0 else "T%d:" % (j + 1)) + nut, "tau_s": 0,
              "coefficient": _num(c, "thermal.nut_coefficients[%d]" % j)}
             for j, c in enumerate(a)]
    terms.append({"signal": "T:" + base, "tau_s": 0,
                  "coefficient": _num(th.get("base_coefficient"), "thermal.base_coefficient")})
    out = dict(doc)
    out["kind"] = "dynamic"
    # dt_s: the board's step; with every tau 0 a step changes nothing, 1 s keeps the scheduler's load small
    out["thermal"] = {"target": th.get("target"), "reference": th.get("reference", "fixed"), "dt_s": 1.0,
                      "intercept": _num(th.get("intercept"), "thermal.intercept"), "terms": terms}
    return out
DYN_SQUARE_BITS = 24  # the spindle speed squared is held as rpm**2 / 2**shq < 2**24
# The certified envelope's default (docs/firmware.md, "Operating envelope"): the training range (the
# document's envelope.temperature_C) widened by this much on both sides. A thermal test never covers
# every condition a machine sees (a faster feed, a hot afternoon); inside the certified envelope the
# firmware evaluates the model and reports EXTRAPOLATING, beyond it it clamps and reports CLAMPED.
DEFAULT_ENVELOPE_MARGIN_K = 15.0


class DynTerm(TypedDict):
    """One filter of a dynamic table in table units (Model._dyn_terms)."""
    src: int  # the signal's firmware source code (DYN_SOURCES; >= 0: a sensor's index; <= -4: a power of a rise)
    u: IntInterval  # the input's integer range (it holds the rest state 0)
    fy: int  # the state's fraction bits: state = input << fy
    a: Fraction  # the discrete lag's weight 1 - exp(-dt/tau) (0: no lag)
    name: str
    tau: Fraction  # s
    ein: Interval  # the integer input minus the exact one (input units; powers of rises only)
    per: Fraction  # the signal's unit per input unit
    signal: str


def _obj(value: object, where: str) -> dict[str, Any]:
    """A document block that must be a JSON object; absent (None) reads as empty."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ExportError("%s must be an object, found %s" % (where, type(value).__name__))
    return value


class Model:
    """The model document reduced to exact numbers in table units (see docs/table-format.md)."""

    def __init__(self, doc: dict[str, Any], ref_position_mm: float | None = None, envelope: Mapping[str, tuple[float, float]] | None = None, margin_K: float = DEFAULT_ENVELOPE_MARGIN_K) -> None:
        """``envelope``: {sensor: (lo_C, hi_C)}, the certified envelope for those sensors (it must
        contain the training range); the others get the training range widened by ``margin_K``."""
        if doc.get("format") != FORMAT:
            raise ExportError("format must be %r (a model document), found %r" % (FORMAT, doc.get("format")))
        kind = doc.get("kind")
        self.doc_kind = kind
        if isinstance(kind, str) and kind in NOT_EXPORTABLE:
            raise ExportError("a %s model cannot be exported: %s" % (kind, NOT_EXPORTABLE[kind]))
        if not isinstance(kind, str) or kind not in TABLE_KINDS:
            raise ExportError("model kind %r cannot be exported (known: %s)" % (kind, ", ".join(TABLE_KINDS)))
        self.kind = TABLE_KINDS[kind]
        if kind == "mr_poly":
            doc = mr_poly_as_dynamic(doc)
            kind = "dynamic"
        sensors = doc.get("sensors") or []
        if not isinstance(sensors, list) or not all(isinstance(s, str) for s in sensors):
            raise ExportError("sensors must be a list of sensor names, found %r" % (sensors,))
        self.sensors = list(sensors)
        env = _obj(doc.get("envelope"), "envelope")
        tenv = _obj(env.get("temperature_C"), "envelope.temperature_C")
        refs = _obj(doc.get("reference_C"), "reference_C")
        thermal = _obj(doc.get("thermal"), "thermal")
        if kind == "screw":
            refs = self._screw_observer_sensors(thermal, tenv, refs)
        # direct: the offset does not depend on the position (linear_direct, dynamic with target "direct")
        self.direct = self.kind == "linear_direct" or (self.kind == "dynamic" and thermal.get("target") == "direct")
        if self.kind == "dynamic" and thermal.get("target") not in ("direct", "slope"):
            raise ExportError("thermal.target must be 'direct' or 'slope', found %r" % (thermal.get("target"),))
        if self.kind == "dynamic" and thermal.get("observer") is not None and thermal.get("reference", "fixed") != "fixed":
            # the observer's gains read rises over the fixed reference_C; a latched reference would move them
            raise ExportError("thermal.observer needs thermal.reference 'fixed' (the gains read T - reference_C), found %r"
                              % (thermal.get("reference"),))
        if thermal.get("reference", "fixed") not in ("fixed", "run_start"):
            raise ExportError("thermal.reference must be 'fixed' or 'run_start', found %r" % (thermal.get("reference"),))
        # "run_start": the firmware may latch the references at a cold start (Evaluator.latch_references),
        # so every integer reference inside the envelope is certified; "fixed": the document's reference_C.
        self.ref_mode = 1 if thermal.get("reference") == "run_start" else 0
        if kind == "screw" and isinstance(thermal.get("reduced"), dict) and thermal["reduced"].get("base_ref") == "run_start":
            # The screw model's ambient term is referenced to each run's start: certify latched references too.
            self.ref_mode = 1
        # per sensor: the certified envelope and the reference (mK), the reference's fraction folded into the intercept
        self.env_lo: list[int] = []
        self.env_hi: list[int] = []
        self.ref: list[int] = []
        self.ref_frac: list[Num] = []
        self.train_lo: list[int] = []  # the training range (mK)
        self.train_hi: list[int] = []
        self.env_source: list[str] = []  # "set" (the caller's envelope) or "default" (training range +- margin)
        envelope = dict(envelope or {})
        unknown = [s for s in envelope if s not in self.sensors]
        if unknown:
            raise ExportError("envelope for sensor %s: not an input of this model (its sensors: %s)"
                              % (unknown[0], ", ".join(self.sensors) or "none"))
        if not (isinstance(margin_K, (int, float)) and math.isfinite(margin_K) and margin_K >= 0):
            raise ExportError("envelope margin %r K: must be a finite number >= 0" % (margin_K,))
        for s in self.sensors:
            if s not in tenv:
                raise ExportError("envelope.temperature_C has no range for sensor %r" % s)
            lo, hi = _pair(tenv[s], "envelope.temperature_C.%s" % s)
            if s not in refs:
                raise ExportError("reference_C has no entry for sensor %r" % s)
            r = F(_num(refs[s], "reference_C.%s" % s)) * 1000
            lo_m, hi_m = math.ceil(F(lo) * 1000), math.floor(F(hi) * 1000)
            if lo_m > hi_m:
                raise ExportError("envelope.temperature_C.%s: empty range %r" % (s, [lo, hi]))
            # the document's envelope is the range the model was fitted over (the training range);
            # the certified envelope is the operating range around it
            self.train_lo.append(lo_m)
            self.train_hi.append(hi_m)
            if s in envelope:
                elo, ehi = envelope[s]
                for v in (elo, ehi):
                    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                        raise ExportError("envelope for sensor %s: %r is not a finite temperature in degC" % (s, v))
                if not elo < ehi:
                    raise ExportError("envelope for sensor %s: low end %g degC must be below the high end %g degC"
                                      % (s, elo, ehi))
                e_lo, e_hi = math.ceil(F(elo) * 1000), math.floor(F(ehi) * 1000)
                if not e_lo <= lo_m <= hi_m <= e_hi:
                    raise ExportError("envelope for sensor %s: %g..%g degC does not contain the training range "
                                      "%.3f..%.3f degC (the model's envelope.temperature_C)"
                                      % (s, elo, ehi, lo_m / 1000.0, hi_m / 1000.0))
                self.env_source.append("set")
            else:
                pad = math.floor(F(margin_K) * 1000)
                e_lo, e_hi = lo_m - pad, hi_m + pad
                self.env_source.append("default")
            lo_m, hi_m = e_lo, e_hi
            self.env_lo.append(lo_m)
            self.env_hi.append(hi_m)
            ri = min(max(rnd(r), lo_m), hi_m) if self.ref_mode else rnd(r)
            self.ref.append(ri)
            # fixed references: the fraction is folded into the intercept so d = t - ref stays an exact int
            self.ref_frac.append(0 if self.ref_mode else r - ri)
        if self.direct:
            self.pos_lo = self.pos_hi = self.pos_ref = 0
        else:
            lo, hi = _pair(env.get("position_mm"), "envelope.position_mm")
            self.pos_lo, self.pos_hi = math.ceil(F(lo) * 1000), math.floor(F(hi) * 1000)
            if self.pos_lo > self.pos_hi:
                raise ExportError("envelope.position_mm: empty range %r" % ([lo, hi],))
            if ref_position_mm is None:
                ref = 0 if self.pos_lo <= 0 <= self.pos_hi else self.pos_lo
            else:
                if not math.isfinite(ref_position_mm):
                    raise ExportError("reference position must be a finite number of mm, got %r" % (ref_position_mm,))
                ref = rnd(F(ref_position_mm) * 1000)
                if not self.pos_lo <= ref <= self.pos_hi:
                    raise ExportError("reference position %s mm is outside envelope.position_mm %s..%s mm"
                                      % (ref_position_mm, lo, hi))
            self.pos_ref = ref
        # S: the temperature-linear part. poly_slope/screw: OU per um (slope); linear_direct: OU.
        if self.kind == "poly_slope":
            coefs = thermal.get("coefficients_um_per_mm_per_K")
            per_mc = F(OU_PER_UM, 1000 * 1000)  # (um/mm/K) -> (OU/um per mK)
            self.b0 = F(_num(thermal.get("intercept_um_per_mm", 0.0), "thermal.intercept_um_per_mm")) * F(OU_PER_UM, 1000)
            self.b_names = ["thermal.coefficients_um_per_mm_per_K.%s" % s for s in self.sensors]
            self.b = [F(_num(_get(coefs, s, "thermal.coefficients_um_per_mm_per_K"), self.b_names[i])) * per_mc
                      for i, s in enumerate(self.sensors)]
        elif self.kind == "dynamic":
            # the temperature-linear part is empty: every term reads a filter state (dyn_terms, after the sensors)
            unit = OU_PER_UM if self.direct else F(OU_PER_UM, 1000)  # um -> OU, or um/mm -> OU/um
            self.b0 = F(_num(thermal.get("intercept", 0.0), "thermal.intercept")) * unit
            self.b_names = ["sensor %s (read by the filters only)" % s for s in self.sensors]
            self.b = [F(0)] * len(self.sensors)
        elif self.kind == "linear_direct":
            coefs = thermal.get("coefficients_um_per_K")
            self.b0 = F(_num(thermal.get("intercept_um", 0.0), "thermal.intercept_um")) * OU_PER_UM
            self.b_names = ["thermal.coefficients_um_per_K.%s" % s for s in self.sensors]
            self.b = [F(_num(_get(coefs, s, "thermal.coefficients_um_per_K"), self.b_names[i])) * F(OU_PER_UM, 1000)
                      for i, s in enumerate(self.sensors)]
        else:
            red = thermal.get("reduced")
            if not isinstance(red, dict):
                raise ExportError("screw model document has no thermal.reduced block (the firmware's recurrence)")
            self.red = red
            alpha = F(_num(red.get("alpha_um_per_mm_per_K"), "thermal.reduced.alpha_um_per_mm_per_K"))
            self.alpha = alpha
            base = red.get("base_sensor")
            self.b0 = F(0)
            self.b = [F(0)] * len(self.sensors)
            self.b_names = ["thermal.reduced.base_sensor(%s)" % s for s in self.sensors]
            if base is not None:
                if base not in self.sensors:
                    raise ExportError("thermal.reduced.base_sensor %r is not in sensors %r" % (base, self.sensors))
                i = self.sensors.index(base)
                # the base term's coefficient: alpha for E_e, plus ambient_expansion's reduced form (format 4 documents
                # state it as ee_um_per_mm_per_K; older ones have alpha alone)
                ee = red.get("ee_um_per_mm_per_K", red.get("alpha_um_per_mm_per_K"))
                self.b[i] = F(_num(ee, "thermal.reduced.ee_um_per_mm_per_K")) * F(OU_PER_UM, 1000 * 1000)
                bref = F(_num(red.get("base_ref_C"), "thermal.reduced.base_ref_C")) * 1000
                self.ref[i] = rnd(bref)
                self.ref_frac[i] = bref - rnd(bref)
            eref = red.get("error_reference", START)
            if eref != START:
                # errors referred to sensor R: E_m lacks alpha*(T_R - T_R,ref)*P, one more temperature-linear
                # coefficient (-alpha on R; 0 when R is also E_e's base sensor: the two cancel)
                if eref not in self.sensors:
                    raise ExportError("thermal.reduced.error_reference %r is not in sensors %r" % (eref, self.sensors))
                i = self.sensors.index(eref)
                rref = F(_num(red.get("error_reference_C"), "thermal.reduced.error_reference_C")) * 1000
                if base == eref and rnd(rref) != self.ref[i]:
                    raise ExportError("thermal.reduced.error_reference_C %r differs from base_ref_C %r for the same sensor %s"
                                      % (red.get("error_reference_C"), red.get("base_ref_C"), eref))
                self.b[i] -= alpha * F(OU_PER_UM, 1000 * 1000)
                self.ref[i] = rnd(rref)
                self.ref_frac[i] = rref - rnd(rref)
        for i in range(len(self.sensors)):
            self.b0 -= self.b[i] * self.ref_frac[i]
        if self.ref_mode:
            self.d_lo = [lo - hi for lo, hi in zip(self.env_lo, self.env_hi)]
            self.d_hi = [hi - lo for lo, hi in zip(self.env_lo, self.env_hi)]
        else:
            self.d_lo = [lo - r for lo, r in zip(self.env_lo, self.ref)]
            self.d_hi = [hi - r for hi, r in zip(self.env_hi, self.ref)]
        self._error_reference(doc)
        if self.kind == "dynamic":
            self._dyn_terms(doc, thermal, env, unit)
        geo = doc.get("geometric") if not self.direct else None
        gc = _obj(geo, "geometric").get("coefficients_um") or [0.0]
        if not isinstance(gc, list):
            raise ExportError("geometric.coefficients_um must be a list of numbers, found %r" % (gc,))
        self.g = [F(_num(c, "geometric.coefficients_um[%d]" % j)) * OU_PER_UM / F(1000) ** j for j, c in enumerate(gc)]
        if len(self.g) - 1 > 6:
            raise ExportError("geometric degree %d: the table holds at most degree 6" % (len(self.g) - 1))

    def _error_reference(self, doc: dict[str, Any]) -> None:
        """``error_ref``: 0 when the model was fitted on raw errors ("start", also a document without the field),
        1 + i when on errors corrected to sensor i (table header byte 58, docs/table-format.md)."""
        ref = doc.get("error_reference", START)
        if ref == START:
            self.error_ref, self.error_reference = 0, START
            return
        if not isinstance(ref, str) or ref not in self.sensors:
            raise ExportError("error_reference %r: the model's errors are corrected to a sensor that is not one of its inputs "
                              "(%s); the table names its reference by input, so refit with that sensor among the inputs"
                              % (ref, ", ".join(self.sensors) or "none"))
        self.error_ref, self.error_reference = 1 + self.sensors.index(ref), ref

    def _dyn_terms(self, doc: dict[str, Any], thermal: dict[str, Any], env: dict[str, Any], unit: Num) -> None:
        """The filters in table units; their coefficients and state boxes are appended to b, d_lo, d_hi, b_names
        (after the sensors, whose own coefficients are 0), so S's ranges include them."""
        dt = thermal.get("dt_s")
        if not isinstance(dt, (int, float)) or isinstance(dt, bool) or not dt > 0 or not math.isfinite(dt):
            raise ExportError("thermal.dt_s must be the filters' step in seconds (> 0), found %r; re-fit the model with "
                              "this tcomp" % (dt,))
        self.dt_ms = rnd(F(dt) * 1000)
        if abs(F(dt) * 1000 - self.dt_ms) > F(1, 10 ** 6) or not 1 <= self.dt_ms <= 3600000:
            raise ExportError("thermal.dt_s=%r is not a whole number of milliseconds in 0.001..3600 s" % (dt,))
        terms = thermal.get("terms")
        if not isinstance(terms, list) or not 1 <= len(terms) <= 8:
            raise ExportError("thermal.terms must list 1..8 terms, found %r" % (terms,))
        n_doc = len(terms)
        extra = self._observer_only_filters(thermal, terms)
        if n_doc + len(extra) > 8:
            raise ExportError("thermal.terms (%d) and the sensors only the observer reads (%s) need %d filters; the table holds 8"
                              % (n_doc, ", ".join(t["signal"][2:] for t in extra), n_doc + len(extra)))
        terms = terms + extra

        def top(key: str, needed: bool) -> int:
            if not needed:
                return 0
            v = env.get(key)
            lo, hi = _pair(v, "envelope.%s" % key) if v is not None else (None, 0.0)
            if lo != 0 or not hi >= 0:  # lo None: the document has no envelope.<key>
                raise ExportError("envelope.%s must be [0, max] for a model reading %s; re-fit the model with this tcomp"
                                  % (key, key.split("_")[0]))
            if hi > (1 << 20):
                raise ExportError("envelope.%s: %r is beyond what the table holds (%d)" % (key, hi, 1 << 20))
            return math.ceil(F(hi))

        signals = [t.get("signal") if isinstance(t, dict) else None for t in terms]
        self.smax = top("spindle_rpm", any(s in ("spindle_krpm", "spindle_krpm2") for s in signals))
        self.fmax = top("feed_mm_min", "feed_m_min" in signals)
        self.shq = max(0, (self.smax * self.smax).bit_length() - DYN_SQUARE_BITS)
        # the square's limbs (firmware Evaluator._inputs); its integer interval as the firmware's mul bounds it
        self.Lq = max(1, min(29, narrow_width(max(self.smax, 1))))
        self.nq = top_limbs_needed((0, self.smax), self.Lq, max(self.smax, 1)) or 0
        if not 1 <= self.nq <= 4:
            raise ExportError("envelope.spindle_rpm: %d rpm cannot be squared in small-int limbs" % self.smax)
        self.q_iv = Recorder().mul(0, (0, self.smax), (0, self.smax), self.Lq, self.nq, self.shq, "spindle speed squared")
        # powers of rises x**e / 2**(shp2 + shp*(e - 2)), one floored factor at a time (Evaluator._inputs): the square is
        # shifted (shp2) to about 2**(Cb - 1), every further factor by the rise's own width (shp), so each power uses
        # the same ~Cb bits and a factor's error is not amplified (|x| / 2**shp < 1). Cb is the largest power bound whose
        # limbs (Lp bits, at most 4 of the rise) stay small ints; the chains are checked against 2**Cb below (the
        # limb-wise interval bound loses the limbs' correlation, hence the bit to spare)
        powered = [(self._sensor_index(sig[3:], "thermal.terms[%d].signal" % j), POWER_PREFIXES[sig[:3]]) for j, sig in enumerate(signals)
                   if isinstance(sig, str) and sig[:3] in POWER_PREFIXES]
        D = max([max(abs(self.d_lo[i]), abs(self.d_hi[i])) for i, _ in powered] + [1])
        self.p_bound, self.Lp, self.np, self.shp2, self.shp = 1, 1, 1, 0, 0
        if powered:
            for cb in range(26, 0, -1):
                L = max(1, min(29, narrow_width(1 << cb)))
                n = top_limbs_needed((-D, D), L, 1 << cb)
                if n is not None and n <= 4:
                    break
            else:
                raise ExportError("the temperature rises of %s (up to %d mK) cannot be raised to a power in small-int limbs"
                                  % (", ".join(self.sensors[i] for i, _ in powered), D))
            db = D.bit_length()
            self.p_bound, self.Lp, self.np = 1 << cb, L, n
            self.shp2 = max(0, 2 * db - (cb - 1))
            self.shp = db
        self.dyn: list[DynTerm] = []
        for j, t in enumerate(terms):
            where = "thermal.terms[%d]" % j if j < n_doc else "observer-only sensor %s" % t["signal"][2:]
            if not isinstance(t, dict):
                raise ExportError("%s must be an object" % where)
            sig = t.get("signal")
            tau = F(_num(t.get("tau_s"), where + ".tau_s"))
            coef = F(_num(t.get("coefficient"), where + ".coefficient"))
            if tau < 0:
                raise ExportError("%s.tau_s must be >= 0, found %r" % (where, t.get("tau_s")))
            ein = (F(0), F(0))
            if isinstance(sig, str) and sig.startswith("T:"):
                if sig[2:] not in self.sensors:
                    raise ExportError("%s.signal %r: sensor %r is not in sensors %r" % (where, sig, sig[2:], self.sensors))
                i = self.sensors.index(sig[2:])
                src, u, per = i, (self.d_lo[i], self.d_hi[i]), F(1, 1000)  # mK -> K
            elif isinstance(sig, str) and sig[:3] in POWER_PREFIXES:
                e = POWER_PREFIXES[sig[:3]]
                i = self.sensors.index(sig[3:])
                u, ein, cs = power_chain(Recorder(), (self.d_lo[i], self.d_hi[i]), e, self.Lp, self.np, self.shp2, self.shp, sig, 0)
                if max(max(-lo, hi) for lo, hi in cs) > self.p_bound:  # the limb width Lp was chosen for this bound
                    raise ExportError("%s: the power of %s outgrows its limbs" % (where, sig[3:]))
                src = -4 - 3 * i - (e - 2)
                per = p2(self.shp2 + self.shp * (e - 2)) / F(1000) ** e  # (mK**e / 2**(shp2 + shp*(e-2))) -> K**e
            elif isinstance(sig, str) and sig in DYN_SOURCES:  # (a list or an object is no signal: unhashable)
                src = DYN_SOURCES[sig]
                if src == -1:
                    u, per = (0, self.smax), F(1, 1000)  # rpm -> krpm
                elif src == -2:
                    u, per = (0, max(-(-self.smax * self.smax // (1 << self.shq)), self.q_iv[0][1])), p2(self.shq) / 10 ** 6  # rpm**2/2**shq -> krpm**2
                else:
                    u, per = (0, self.fmax), F(1, 1000)  # mm/min -> m/min
            else:
                raise ExportError("%s.signal must be 'T:<sensor>', 'T2:'..'T4:<sensor>' or one of %s, found %r"
                                  % (where, ", ".join(DYN_SOURCES), sig))
            if not u[0] <= 0 <= u[1]:
                raise ExportError("%s: the input range %r does not hold the rest state 0" % (where, u))
            fy = max(0, frac_bits(max(u[1] - u[0], 1), ACC, cap=28))
            # the host's discrete lag (host/learning/empirical/dynamic.py): a = 1 - exp(-dt/tau) in doubles, exactly
            import numpy as np
            a = F(float(1.0 - np.exp(-(self.dt_ms / 1000.0) / float(tau)))) if tau > 0 else F(0)
            name = ("thermal.terms[%d] (%s, tau %g s)" % (j, sig, float(tau)) if j < n_doc else
                    "observer-only sensor %s (a filter of tau 0 and coefficient 0)" % sig[2:])
            self.dyn.append(DynTerm(src=src, u=u, fy=fy, a=a, name=name, tau=tau, ein=ein, per=per, signal=sig))
            self.b.append(coef * unit * per / p2(fy))  # output scale per state unit
            self.d_lo.append(u[0] << fy)
            self.d_hi.append(u[1] << fy)
            self.b_names.append(name)
        self._observer(thermal.get("observer"))

    def _observer_only_filters(self, thermal: dict[str, Any], terms: list[Any]) -> list[dict[str, Any]]:
        """Sensors only the observer reads (the dynamic option observer_sensors, docs/model-format.md): a sensor of
        ``sensors`` that no term reads and an observer gain "T:<sensor>" does. Each becomes a filter with tau 0 and
        coefficient 0 after the terms (table format 5 unchanged: the board reads it as any filter's input, the offset
        does not depend on it, and the observer's gain has a filter input to read)."""
        obs = thermal.get("observer")
        if not isinstance(obs, dict) or not isinstance(obs.get("states"), list):
            return []
        read = {t.get("signal") for t in terms if isinstance(t, dict)}
        gained = {k for st in obs["states"] if isinstance(st, dict) and isinstance(st.get("gains"), dict) for k in st["gains"]}
        return [{"signal": "T:" + s, "tau_s": 0.0, "coefficient": 0.0} for s in self.sensors
                if "T:" + s not in read and "T:" + s in gained]

    def _observer(self, obs: object) -> None:
        """The observer's gains in table units (issue 21; host/learning/empirical/observer.py): ``obs_gain[j][m]``, the
        exact coefficient of filter m's integer input in lag state j's integer estimate (state units 2**-fy[j]); a signal's
        gain goes to the first filter reading it. ``None``: no observer (the filters start at rest)."""
        self.observer: dict[str, Any] | None = None
        self.obs_gain: list[list[Fraction]] | None = None
        self.settle_s = 0
        self.settle_nr_s = 0
        self.supplied = {}
        if obs is None:
            return
        where = "thermal.observer"
        obs = _obj(obs, where)
        if obs.get("method") != "static_state_estimate":
            raise ExportError("%s.method must be 'static_state_estimate', found %r" % (where, obs.get("method")))
        settle = _num(obs.get("settle_s"), where + ".settle_s")
        if not 0 <= settle <= (1 << 30) - 1:
            raise ExportError("%s.settle_s must be 0..%d s, found %r" % (where, (1 << 30) - 1, settle))
        self.settle_s = math.ceil(F(settle))
        first = {}
        for m, t in enumerate(self.dyn):
            first.setdefault(t["signal"], m)
        lagged = [j for j, t in enumerate(self.dyn) if t["tau"] > 0]
        states = obs.get("states")
        if not isinstance(states, list) or [s.get("term") if isinstance(s, dict) else None for s in states] != lagged:
            raise ExportError("%s.states must list one object per lag term (thermal.terms with tau_s > 0), in term order: "
                              "terms %s" % (where, lagged))
        # the states the controller supplies (fit option spindle_states=controller): the table's tauc, the filter's
        # time constant in ms, by which the controller runs the same lag over its record (docs/protocol.md "Supplied
        # lag states"); their gains (if any) are the board's estimate until the controller's values come
        self.supplied: dict[int, int] = {}
        for s in states:
            if isinstance(s, dict) and "source" in s:
                j = s.get("term")
                t = self.dyn[j] if isinstance(j, int) and 0 <= j < len(self.dyn) else None
                if s["source"] != "controller" or t is None or not isinstance(j, int) or t["src"] not in (-1, -2, -3) or s.get("bound") != 0:
                    raise ExportError("%s.states[term %r]: source %r on %s: only a lag of the spindle speed, its square or the "
                                      "feed, with bound 0, can be supplied by the controller" % (
                                          where, j, s["source"], t["signal"] if t is not None else "no such term"))
                tau_ms = round(t["tau"] * 1000)
                if not 0 < tau_ms <= (1 << 30) - 1:
                    raise ExportError("%s.states[term %d]: tau %g s is outside what the table carries (1 ms..%d ms)"
                                      % (where, j, float(t["tau"]), (1 << 30) - 1))
                self.supplied[j] = tau_ms
        if len(self.supplied) > MAX_SUPPLIED:
            raise ExportError("%s: %d lag states are supplied by the controller (terms %s); the board takes at most %d"
                              % (where, len(self.supplied), sorted(self.supplied), MAX_SUPPLIED))
        # the table's settle_nr: SETTLING of a board started without the controller's values (those states at their
        # gains' estimate); a document without it (fitted before stop 33) gets SETTLE_NEVER (2**30 - 1 s, the table's
        # largest): SETTLING until the values come, as format 7 did
        nr = obs.get("settle_without_record_s")
        if nr is not None and not self.supplied:
            raise ExportError("%s.settle_without_record_s belongs to an observer with states the controller supplies" % where)
        if self.supplied:
            nr = SETTLE_NEVER if nr is None else _num(nr, where + ".settle_without_record_s")
            if not self.settle_s <= nr <= SETTLE_NEVER:
                raise ExportError("%s.settle_without_record_s must be settle_s..%d s, found %r" % (where, SETTLE_NEVER, nr))
            self.settle_nr_s = math.ceil(F(nr))
        nf = len(self.dyn)
        self.obs_gain = [[F(0)] * nf for _ in range(nf)]
        for k, st in enumerate(states):
            j = st["term"]
            gains = _obj(st.get("gains"), "%s.states[%d].gains" % (where, k))
            for name, g in gains.items():
                if name not in first:
                    raise ExportError("%s.states[%d].gains: signal %r is not read by any term (the terms read %s)"
                                      % (where, k, name, ", ".join(first)))
                m = first[name]
                g = F(_num(g, "%s.states[%d].gains.%s" % (where, k, name)))
                # y_j = sum g x_m in the signals' units; x_m = per_m x Uc[m], Y[j] = y_j / per_j x 2**fy[j]
                self.obs_gain[j][m] += g * self.dyn[m]["per"] * p2(self.dyn[j]["fy"]) / self.dyn[j]["per"]
        self.observer = obs

    def _screw_observer_sensors(self, thermal: dict[str, Any], tenv: dict[str, Any], refs: dict[str, Any]) -> dict[str, Any]:
        """A screw document's observer (thermal.observer, host/learning/screw/observer.py; issue 21) read for the table:
        ``screw_obs`` (None: not carried, ``screw_obs_note`` says why) with the nut sensor appended to the table's sensors
        (its reference is the observer's under base_ref "fixed", latched at a cold start under "run_start"). Returns the
        references with the nut sensor's."""
        self.screw_obs: dict[str, Any] | None = None
        self.screw_obs_note: str | None = None
        obs = thermal.get("observer")
        if obs is None:
            return refs
        where = "thermal.observer"
        obs = _obj(obs, where)
        if obs.get("method") != "static_state_estimate":
            raise ExportError("%s.method must be 'static_state_estimate', found %r" % (where, obs.get("method")))
        nut = _sensor_name(obs.get("sensor"), where + ".sensor")
        air = _sensor_name(obs.get("air_sensor"), where + ".air_sensor")
        red = thermal.get("reduced")
        M = red.get("segments") if isinstance(red, dict) else None
        gains = obs.get("gains_K_per_K")
        if not isinstance(gains, list) or len(gains) != M:
            raise ExportError("%s.gains_K_per_K must list %r numbers (one per reduced segment), found %r" % (where, M, gains))
        gains = [F(_num(g, "%s.gains_K_per_K[%d]" % (where, i))) for i, g in enumerate(gains)]
        settle = _num(obs.get("settle_s"), where + ".settle_s")
        if not 0 <= settle <= (1 << 30) - 1:
            raise ExportError("%s.settle_s must be 0..%d s, found %r" % (where, (1 << 30) - 1, settle))
        if air not in self.sensors:
            raise ExportError("%s.air_sensor %r is not in sensors %r" % (where, air, self.sensors))
        if nut == air or nut in self.sensors:
            raise ExportError("%s.sensor %r must be a sensor the model itself does not read (sensors %r)" % (where, nut, self.sensors))
        if nut not in tenv:
            self.screw_obs_note = ("the document records no envelope.temperature_C for the observer's nut sensor %s (fitted "
                                   "before tcomp carried the observer into the table): re-fit the model" % nut)
            return refs
        run_start = isinstance(red, dict) and red.get("base_ref") == "run_start"
        ref_C = obs.get("reference_C")
        exact: dict[str, Fraction] | None = None
        if run_start:
            if ref_C is not None:
                raise ExportError("%s.reference_C must be null under thermal.reduced.base_ref 'run_start' (the board "
                                  "latches the references), found %r" % (where, ref_C))
            lo, hi = _pair(tenv[nut], "envelope.temperature_C.%s" % nut)
            nut_ref = (lo + hi) / 2  # a placeholder: the board latches every reference at a cold start (ref_mode 1)
        else:
            ref_C = _obj(ref_C, where + ".reference_C")
            exact = {n: F(_num(ref_C.get(n), "%s.reference_C.%s" % (where, n))) * 1000 for n in (nut, air)}
            nut_ref = ref_C[nut]
        self.sensors.append(nut)
        self.screw_obs = {"sensor": nut, "air_sensor": air, "gains": gains, "settle_s": math.ceil(F(settle)),
                          "reference_mC": exact, "document": obs}
        return dict(refs, **{nut: nut_ref})

    def _sensor_index(self, name: str, where: str) -> int:
        if name not in self.sensors:
            raise ExportError("%s: sensor %r is not in sensors %r" % (where, name, self.sensors))
        return self.sensors.index(name)

    # real ranges ----------------------------------------------------------
    def s_range(self) -> Interval:
        lo = hi = self.b0
        for b, a, c in zip(self.b, self.d_lo, self.d_hi):
            lo += min(b * a, b * c)
            hi += max(b * a, b * c)
        return (lo, hi)

    def s_bound(self) -> Num:
        """Bound of |every partial sum| of S."""
        return abs(self.b0) + sum(abs(b) * max(abs(a), abs(c)) for b, a, c in zip(self.b, self.d_lo, self.d_hi))

    def p_iv(self) -> Interval:
        return (F(self.pos_lo), F(self.pos_hi))

    def horner_range(self, j: int) -> Interval:
        """Sound interval of h_j(p) = sum_{k>=j} g_k p^(k-j) over the position envelope (interval Horner)."""
        P = self.p_iv()
        h = (self.g[-1], self.g[-1])
        for k in range(len(self.g) - 2, j - 1, -1):
            h = iv_add(iv_mul(h, P), (self.g[k], self.g[k]))
        return h


def _sensor_name(v: object, where: str) -> str:
    if not isinstance(v, str):
        raise ExportError("%s must be a sensor's name, found %r" % (where, v))
    return v


def _num(v: object, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ExportError("%s: expected a finite number, got %r" % (where, v))
    return v


def _get(d: object, key: str, where: str) -> Any:
    if not isinstance(d, dict) or key not in d:
        raise ExportError("%s has no entry for sensor %r" % (where, key))
    return d[key]


def _pair(v: object, where: str) -> tuple[float, float]:
    if not (isinstance(v, (list, tuple)) and len(v) == 2):
        raise ExportError("%s: expected [lo, hi], got %r" % (where, v))
    return _num(v[0], where + "[0]"), _num(v[1], where + "[1]")
