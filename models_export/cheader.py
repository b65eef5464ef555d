"""The table as a C header, with the firmware's integer evaluation in C.

For controllers whose firmware is C: ``static const`` coefficient arrays, the
raw table bytes (for the same upload path as the MicroPython firmware), and
static functions that perform exactly the operations of firmware/evaluate.py
in the same order, so the certificate in the header comment applies. Every
intermediate fits int32_t (the certificate bounds it by 2**30); C's
undefined cases are avoided: right shifts by 31 or more are computed as the
sign, left shifts as multiplications. Right shift of a negative int32_t is
assumed arithmetic (gcc, clang, arm-none-eabi, IAR, Keil all do so).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

# The ignore: firmware/table.py defines COMMON, POSITION, SCREW, SCREW_OBS as _NAME and publishes them under NAME through
# globals() on CPython only, which pyright cannot follow.
from firmware.table import COMMON, KINDS, POSITION, SCREW, SCREW_OBS, SENSOR_FIELDS  # pyright: ignore[reportAttributeAccessIssue]
from models_export.tableformat import spec_names

if TYPE_CHECKING:
    from models_export.export import Export

# Fraction bits of coefficients: recorded in the table for its readers, never used by the
# evaluation (firmware/evaluate.py reads none of them; tests/export/test_export_table.py checks).
INFORMATIONAL = ("fS", "fb", "fG", "fh")


def _groups(spec, sensor_block=False):
    """(scalars, arrays) of one section of firmware/table.py, in table order, without INFORMATIONAL."""
    names = [(n, is_list) for n, is_list in spec_names(spec) if n not in INFORMATIONAL]
    arrays = (SENSOR_FIELDS.split() if sensor_block else []) + [n for n, is_list in names if is_list]
    return tuple(n for n, is_list in names if not is_list), tuple(arrays)


# the coefficients the C evaluator reads, section by section (the table's own order)
_SECTIONS = {"all": _groups(COMMON, sensor_block=True), "position": _groups(POSITION), "screw": _groups(SCREW),
             "screw_obs": _groups(SCREW_OBS)}
SCALARS = {g: v[0] for g, v in _SECTIONS.items()}
ARRAYS = {g: v[1] for g, v in _SECTIONS.items()}
C_KINDS = ("poly_slope", "linear_direct", "screw_reduced")  # the kinds with a C evaluator

CODE = r"""
#define TCOMP_CLAMP_POSITION 0x1000000u
#define TCOMP_CLAMP_TRAVEL 0x2000000u
#define TCOMP_CLAMP_STATE 0x4000000u
#define TCOMP_FEED_W_BITS 19

typedef struct {
    int32_t temps[TCOMP_N_SENSORS_ALLOC]; /* milli-degC, channel order; write, then tcomp_update() */
    int32_t ref[TCOMP_N_SENSORS_ALLOC]; /* reference temperatures (tcomp_latch_references when TCOMP_REF_MODE == 1) */
    int32_t S;
    uint32_t flags; /* bit i: sensor i clamped; TCOMP_CLAMP_* */
    uint32_t extrap; /* bit i: sensor i evaluated outside the training range (status EXTRAPOLATING) */
    int32_t pos_ref;
#if TCOMP_KIND == TCOMP_KIND_SCREW_REDUCED
    int32_t T[TCOMP_M], Tn[TCOMP_M], u[TCOMP_M], w[TCOMP_M], limbs[TCOMP_M * TCOMP_NS], cum[TCOMP_M + 1], segslope[TCOMP_M];
    int32_t x, F, dir; /* dir: direction of the last position change (+1, -1, 0: none or feed/range mode) */
    int32_t da, da0; /* air over its reference (milli-K) at the last update and at the last step */
    int have_x, feed;
#endif
} tcomp_eval_t;

static int32_t tcomp_shift(int32_t p, int sh)
{
    if (sh > 0)
        return sh > 30 ? (p < 0 ? -1 : 0) : p >> sh;
    return p == 0 ? 0 : p * (int32_t)(1L << -sh);
}

/* floor-ish c*x/2^sh with x split into n limbs of L bits, top limb signed (firmware Evaluator._mul) */
static int32_t tcomp_mul(int32_t c, int32_t x, int L, int n, int sh)
{
    int32_t m = (int32_t)((1L << L) - 1), r = 0;
    while (n > 1) {
        r += tcomp_shift(c * (x & m), sh);
        x >>= L;
        sh -= L;
        n--;
    }
    return r + tcomp_shift(c * x, sh);
}

static void tcomp_update(tcomp_eval_t *e)
{
    uint32_t fl = 0, ex = 0;
    int32_t s = TCOMP_S0;
    int i;
    for (i = 0; i < TCOMP_N_SENSORS; i++) {
        int32_t v = e->temps[i];
        if (v < tcomp_env_lo[i]) { v = tcomp_env_lo[i]; fl |= 1u << i; }
        else if (v > tcomp_env_hi[i]) { v = tcomp_env_hi[i]; fl |= 1u << i; }
        if (v < tcomp_train_lo[i] || v > tcomp_train_hi[i]) ex |= 1u << i;
        s += tcomp_mul(tcomp_b[i], v - e->ref[i], TCOMP_LT, TCOMP_NT, tcomp_shb[i]);
#if TCOMP_KIND == TCOMP_KIND_SCREW_REDUCED
        if (i == TCOMP_AIR) e->da = v - e->ref[i];
#endif
    }
    e->S = s;
    e->flags = (e->flags & ~0xFFFFFFu) | fl;
    e->extrap = ex;
}

#if TCOMP_KIND == TCOMP_KIND_SCREW_REDUCED
static void tcomp_refresh(tcomp_eval_t *e);
/* start state: in equilibrium with the air (construction, latch) */
static void tcomp_settle(tcomp_eval_t *e)
{
    int32_t v = 0;
    int i;
    if (TCOMP_AIR >= 0) {
        v = tcomp_mul(TCOMP_KA, e->da, TCOMP_LT, TCOMP_NT, TCOMP_SHKA);
        if (v < TCOMP_TLO) v = TCOMP_TLO;
        else if (v > TCOMP_TMAX) v = TCOMP_TMAX;
    }
    for (i = 0; i < TCOMP_M; i++) e->T[i] = v;
    e->da0 = e->da;
    tcomp_refresh(e);
}

#if TCOMP_OBS
/* sensor i's reading clamped to its envelope, over its reference (milli-K), as tcomp_update reads it */
static int32_t tcomp_rise(const tcomp_eval_t *e, int i)
{
    int32_t v = e->temps[i];
    if (v < tcomp_env_lo[i]) v = tcomp_env_lo[i];
    else if (v > tcomp_env_hi[i]) v = tcomp_env_hi[i];
    return v - e->ref[i];
}
#endif

/* the screw observer's start (firmware Evaluator.estimate; TCOMP_OBS 1, format 6): after tcomp_update with every
   sensor good, at a start without a trusted stored state (not after a latch: that is a cold start); the segment
   states from the nut sensor TCOMP_SN's rise over TCOMP_SR. Without an observer it is tcomp_settle, the cold start.
   The caller raises its SETTLING for TCOMP_SETTLE_S seconds from here (docs/firmware.md). */
static void tcomp_estimate(tcomp_eval_t *e)
{
    tcomp_settle(e);
#if TCOMP_OBS
    {
    int32_t r, a;
    int i;
    r = tcomp_rise(e, TCOMP_SN) - tcomp_rise(e, TCOMP_SR);
    if (r > TCOMP_RN) r = TCOMP_RN;
    else if (r < -TCOMP_RN) r = -TCOMP_RN;
    a = e->T[0];
    for (i = 0; i < TCOMP_M; i++) {
        int32_t v = a + tcomp_mul(tcomp_Gn[i], r, TCOMP_LR, TCOMP_NR, tcomp_shGn[i]) + tcomp_rN[i];
        if (v < TCOMP_TLO) v = TCOMP_TLO;
        else if (v > TCOMP_TMAX) v = TCOMP_TMAX;
        e->T[i] = v;
    }
    tcomp_refresh(e);
    }
#endif
}
#endif

#if TCOMP_REF_MODE == 1
/* models fitted on rises from the run start: latch the current temperatures as references (cold start) */
static void tcomp_latch_references(tcomp_eval_t *e)
{
    int i;
    for (i = 0; i < TCOMP_N_SENSORS; i++) {
        int32_t v = e->temps[i];
        e->ref[i] = v < tcomp_env_lo[i] ? tcomp_env_lo[i] : (v > tcomp_env_hi[i] ? tcomp_env_hi[i] : v);
    }
    tcomp_update(e);
#if TCOMP_KIND == TCOMP_KIND_SCREW_REDUCED
    tcomp_settle(e);
#endif
}
#endif

static int32_t tcomp_clamp_pos(tcomp_eval_t *e, int32_t pos)
{
    if (pos < TCOMP_POS_LO) { e->flags |= TCOMP_CLAMP_POSITION; return TCOMP_POS_LO; }
    if (pos > TCOMP_POS_HI) { e->flags |= TCOMP_CLAMP_POSITION; return TCOMP_POS_HI; }
    e->flags &= ~TCOMP_CLAMP_POSITION;
    return pos;
}

#if TCOMP_KIND == TCOMP_KIND_SCREW_REDUCED
static int32_t tcomp_seg(const tcomp_eval_t *e, int32_t p)
{
    int32_t x = p - TCOMP_FIXED_END;
    int k = 0;
    if (x <= 0) return 0;
    if (x >= tcomp_edges[TCOMP_M]) return e->cum[TCOMP_M];
    while (tcomp_edges[k + 1] <= x) k++;
    return e->cum[k] + tcomp_mul(x - tcomp_edges[k], e->segslope[k], TCOMP_LX, TCOMP_NX, TCOMP_SHX);
}

static void tcomp_refresh(tcomp_eval_t *e)
{
    int32_t c = 0;
    int i;
    for (i = 0; i < TCOMP_M; i++) {
        e->cum[i] = c;
        c += tcomp_mul(tcomp_G2[i], e->T[i], TCOMP_LS, TCOMP_NS, tcomp_shG2[i]);
        e->segslope[i] = tcomp_mul(TCOMP_H, e->T[i], TCOMP_LS, TCOMP_NS, TCOMP_SHH);
    }
    e->cum[TCOMP_M] = c;
}

/* nut travel per segment from a position report (um) */
static void tcomp_advance_position(tcomp_eval_t *e, int32_t pos)
{
    int32_t x = tcomp_clamp_pos(e, pos) - TCOMP_FIXED_END, a, b;
    int i;
    if (!e->have_x) { e->have_x = 1; e->x = x; return; }
    a = e->x; b = x; e->x = x;
    if (a == b) return;
    if (a > b) { int32_t t = a; a = b; b = t; e->dir = -1; } else e->dir = 1;
    for (i = 0; i < TCOMP_M; i++) {
        int32_t lo = tcomp_edges[i] > a ? tcomp_edges[i] : a;
        int32_t hi = tcomp_edges[i + 1] < b ? tcomp_edges[i + 1] : b;
        if (hi > lo) {
            int32_t v = e->u[i] + (hi - lo);
            if (v > TCOMP_UMAX) { v = TCOMP_UMAX; e->flags |= TCOMP_CLAMP_TRAVEL; }
            e->u[i] = v;
        }
    }
}

/* fallback without position reports: feed (mm/min) spread over [lo, hi] (um) every step */
static void tcomp_set_feed(tcomp_eval_t *e, int32_t feed, int32_t lo_um, int32_t hi_um)
{
    int32_t f = feed >= 0 ? feed : -feed, a, b, r;
    int i, k;
    if (f > TCOMP_FMAX) { f = TCOMP_FMAX; e->flags |= TCOMP_CLAMP_TRAVEL; }
    e->F = (f * TCOMP_DT_MS) / 60;
    a = tcomp_clamp_pos(e, lo_um) - TCOMP_FIXED_END;
    b = tcomp_clamp_pos(e, hi_um) - TCOMP_FIXED_END;
    if (a > b) { int32_t t = a; a = b; b = t; }
    if (a < 0) a = 0;
    if (b > tcomp_edges[TCOMP_M]) b = tcomp_edges[TCOMP_M];
    r = b - a;
    for (i = 0; i < TCOMP_M; i++) {
        int32_t lo = tcomp_edges[i] > a ? tcomp_edges[i] : a;
        int32_t hi = tcomp_edges[i + 1] < b ? tcomp_edges[i + 1] : b;
        e->w[i] = 0;
        if (r <= 0) {
            if ((tcomp_edges[i] <= a && a < tcomp_edges[i + 1]) || (i == TCOMP_M - 1 && a == tcomp_edges[TCOMP_M]))
                e->w[i] = 1 << TCOMP_FEED_W_BITS;
        } else if (hi > lo) {
            int32_t q = 0, rem = hi - lo;
            if (rem >= r) { q = 1; rem -= r; }
            for (k = 0; k < TCOMP_FEED_W_BITS; k++) {
                rem <<= 1; q <<= 1;
                if (rem >= r) { rem -= r; q += 1; }
            }
            e->w[i] = q;
        }
    }
    e->feed = 1;
    e->dir = 0; /* the feed/range state has no direction */
}

/* one step of T <- T + C*T + B*g(U)*u + Bu*U - D*U*(T - a0) + W0*a0 + W1*a1 (U: the step's total travel,
   g(U) = g0 + Gv*U: speed_dependent_heat, D: moving_convection), every TCOMP_DT_MS ms */
static void tcomp_step(tcomp_eval_t *e)
{
    const int32_t mask = (int32_t)((1L << TCOMP_LS) - 1);
    uint32_t fl = 0;
    int32_t U = 0, g = 0, a0 = 0;
    int i, j, k;
    int32_t U0 = 0;
    if (e->feed) {
        for (i = 0; i < TCOMP_M; i++) {
            int32_t v;
            U0 += e->u[i];
            v = e->u[i] + tcomp_mul(e->w[i], e->F, 10, 3, TCOMP_FEED_W_BITS);
            if (v > TCOMP_UMAX) { v = TCOMP_UMAX; e->flags |= TCOMP_CLAMP_TRAVEL; }
            e->u[i] = v;
        }
    }
    for (i = 0; i < TCOMP_M; i++) {
        U += e->u[i];
        if (U > TCOMP_UMAX) { U = TCOMP_UMAX; e->flags |= TCOMP_CLAMP_TRAVEL; }
    }
    if (e->feed) { U = U0 + e->F; if (U > TCOMP_UMAX) U = TCOMP_UMAX; } /* the spread's fractions sum to 1 */
    if (TCOMP_FG) g = TCOMP_G0 + tcomp_mul(TCOMP_GV, U, TCOMP_LU, TCOMP_NU, TCOMP_SHGV);
    if (TCOMP_FE && TCOMP_AIR >= 0) {
        a0 = tcomp_mul(TCOMP_KA, e->da0, TCOMP_LT, TCOMP_NT, TCOMP_SHKA);
        if (a0 < TCOMP_TLO) a0 = TCOMP_TLO;
        else if (a0 > TCOMP_TMAX) a0 = TCOMP_TMAX;
    }
    for (j = 0; j < TCOMP_M; j++) {
        int32_t x = e->T[j];
        for (k = 0; k < TCOMP_NS - 1; k++) { e->limbs[k * TCOMP_M + j] = x & mask; x >>= TCOMP_LS; }
        e->limbs[(TCOMP_NS - 1) * TCOMP_M + j] = x;
    }
    for (i = 0; i < TCOMP_M; i++) {
        int32_t acc = 0, v;
        int sh = TCOMP_FC - TCOMP_GS;
        for (k = 0; k < TCOMP_NS; k++) {
            int32_t r = 0;
            for (j = 0; j < TCOMP_M; j++) r += tcomp_C[i * TCOMP_M + j] * e->limbs[k * TCOMP_M + j];
            acc += tcomp_shift(r, sh);
            sh -= TCOMP_LS;
        }
        {
            int32_t ui = e->u[i];
            if (TCOMP_FG) ui = tcomp_mul(g, ui, TCOMP_LGU, TCOMP_NGU, TCOMP_FG);
            acc += tcomp_mul(tcomp_B[i], ui, TCOMP_LU, TCOMP_NU, tcomp_shB[i]) + tcomp_rS[i];
        }
        if (tcomp_D[i]) {
            int32_t eps = tcomp_mul(tcomp_D[i], U, TCOMP_LU, TCOMP_NU, tcomp_shD[i]);
            acc -= tcomp_mul(eps, e->T[i] - a0, TCOMP_LY, TCOMP_NY, TCOMP_FE - TCOMP_GS);
        }
        if (tcomp_Bu[i]) acc += tcomp_mul(tcomp_Bu[i], U, TCOMP_LU, TCOMP_NU, tcomp_shBu[i]);
        if (TCOMP_AIR >= 0) {
            acc += tcomp_mul(tcomp_W0[i], e->da0, TCOMP_LT, TCOMP_NT, tcomp_shW0[i]);
            acc += tcomp_mul(tcomp_W1[i], e->da, TCOMP_LT, TCOMP_NT, tcomp_shW1[i]);
        }
        v = e->T[i] + (acc >> TCOMP_GS);
        if (v < TCOMP_TLO) v = TCOMP_TLO;
        else if (v > TCOMP_TMAX) { v = TCOMP_TMAX; fl = TCOMP_CLAMP_STATE; }
        e->Tn[i] = v;
    }
    for (i = 0; i < TCOMP_M; i++) { e->T[i] = e->Tn[i]; e->u[i] = 0; }
    e->da0 = e->da;
    e->flags = (e->flags & ~TCOMP_CLAMP_STATE) | fl;
    tcomp_refresh(e);
}
#endif

/* total offset (geometric + thermal) at pos (um), in 0.01 um */
static int32_t tcomp_offset_at(tcomp_eval_t *e, int32_t pos)
{
#if TCOMP_KIND == TCOMP_KIND_LINEAR_DIRECT
    (void)pos;
    return (e->S + TCOMP_RL) >> TCOMP_FO;
#else
    int32_t p = tcomp_clamp_pos(e, pos), h = tcomp_G[TCOMP_DEGREE], acc;
    int j;
    for (j = TCOMP_DEGREE - 1; j >= 0; j--)
        h = tcomp_mul(p, h, TCOMP_LG, TCOMP_NG, tcomp_shg[j]) + tcomp_G[j];
    acc = h + tcomp_mul(p, e->S, TCOMP_LW, TCOMP_NW, TCOMP_SHW);
#if TCOMP_KIND == TCOMP_KIND_SCREW_REDUCED
    acc += tcomp_seg(e, p);
    if (e->dir > 0) acc += TCOMP_RV; /* reversal error: as the last position change went */
    else if (e->dir < 0) acc -= TCOMP_RV;
#endif
    return (acc + TCOMP_RO) >> TCOMP_FO;
#endif
}

/* thermal offset at the reference position, 0.01 um (with tcomp_slope: the Siemens/Beckhoff pair) */
static int32_t tcomp_ref_offset(tcomp_eval_t *e)
{
#if TCOMP_KIND == TCOMP_KIND_LINEAR_DIRECT
    return tcomp_offset_at(e, 0);
#else
    int32_t acc = tcomp_mul(e->pos_ref, e->S, TCOMP_LW, TCOMP_NW, TCOMP_SHW);
#if TCOMP_KIND == TCOMP_KIND_SCREW_REDUCED
    acc += tcomp_seg(e, e->pos_ref);
#endif
    return (acc + TCOMP_RT) >> TCOMP_FO;
#endif
}

/* thermal slope in 0.01 um/m */
static int32_t tcomp_slope(tcomp_eval_t *e)
{
#if TCOMP_KIND == TCOMP_KIND_LINEAR_DIRECT
    (void)e;
    return 0;
#else
    int32_t acc = tcomp_mul(TCOMP_KS, e->S, TCOMP_LW, TCOMP_NW, TCOMP_SHK);
#if TCOMP_KIND == TCOMP_KIND_SCREW_REDUCED
    acc += tcomp_mul(TCOMP_KC, tcomp_seg(e, TCOMP_POS_HI) - tcomp_seg(e, TCOMP_POS_LO), TCOMP_LC, TCOMP_NC, TCOMP_SHC);
#endif
    return (acc + TCOMP_RK) >> TCOMP_FK;
#endif
}

static void tcomp_init(tcomp_eval_t *e)
{
    int i;
    for (i = 0; i < TCOMP_N_SENSORS_ALLOC; i++) {
        e->temps[i] = (i < TCOMP_N_SENSORS && tcomp_env_lo[i] <= 0 && 0 <= tcomp_env_hi[i]) ? 0 : tcomp_env_lo[i];
        e->ref[i] = tcomp_ref[i];
    }
    e->flags = 0;
    e->pos_ref = TCOMP_POS_REF;
#if TCOMP_KIND == TCOMP_KIND_SCREW_REDUCED
    for (i = 0; i < TCOMP_M; i++) { e->T[i] = 0; e->u[i] = 0; e->w[i] = 0; }
    e->have_x = 0; e->feed = 0; e->x = 0; e->F = 0; e->dir = 0; e->da = 0; e->da0 = 0;
#endif
    tcomp_update(e);
#if TCOMP_KIND == TCOMP_KIND_SCREW_REDUCED
    tcomp_settle(e);
#endif
}
"""


def _array(name, values):
    vals = list(values) or [0]
    body = ", ".join(str(v) for v in vals)
    return "static const int32_t tcomp_%s[%d] = {%s};\n" % (name, len(vals), body)


def c_header(ex: Export, guard: str = "TCOMP_TABLE_H") -> str:
    f = ex.fields
    r = ex.report
    kind = f["kind"]
    if kind not in C_KINDS:
        from models_export.certify import ExportError
        raise ExportError("--c-header: %s tables have no C evaluator yet; export the table only" % kind)
    groups = ["all"] + (["position"] if kind != "linear_direct" else []) + (["screw", "screw_obs"] if kind == "screw_reduced" else [])
    out = []
    out.append("/* tcomp coefficient table, generated by `tcomp export` (docs/table-format.md).\n")
    out.append(" * model kind %s, axis %s, model sha256 %s\n" % (kind, f["axis"], r["provenance_sha256"]))
    out.append(" * sensors (channel order): %s\n" % (", ".join(f["sensors"]) or "none"))
    out.append(" * units: temperatures milli-degC, positions um, offsets 0.01 um, slopes 0.01 um/m\n")
    out.append(" * certified over the envelope: max |integer - model| = %.6f um (limit %.3f um),\n"
               " * every intermediate |x| < 2^30, min headroom %.3f bits.\n" % (r["max_error_um"], r["limit_um"], r["min_headroom_bits"]))
    out.append(" * The functions below perform the operations of firmware/evaluate.py in the same order;\n"
               " * the certificate holds for them only if they are not reordered. Usage:\n"
               " *   tcomp_eval_t e; tcomp_init(&e); e.temps[i] = ...; tcomp_update(&e); tcomp_offset_at(&e, pos_um);\n"
               " * screw tables: tcomp_advance_position(&e, pos_um) on each report, tcomp_step(&e) every TCOMP_DT_MS;\n"
               " * at a start without a trusted stored state, tcomp_estimate(&e) after the first all-good tcomp_update\n"
               " * (the screw observer when TCOMP_OBS is 1: SETTLING for TCOMP_SETTLE_S s is the caller's).\n */\n")
    out.append("#ifndef %s\n#define %s\n#include <stdint.h>\n\n" % (guard, guard))
    for code, name in sorted(KINDS.items()):  # the table's kind codes (firmware/table.py)
        out.append("#define TCOMP_KIND_%s %d\n" % (name.upper(), code))
    out.append("#define TCOMP_KIND TCOMP_KIND_%s\n" % kind.upper())
    out.append("#define TCOMP_N_SENSORS %d\n#define TCOMP_N_SENSORS_ALLOC %d\n" % (len(f["sensors"]), max(1, len(f["sensors"]))))
    out.append("#define TCOMP_REF_MODE %d /* 1: references may be latched (tcomp_latch_references) */\n" % f.get("ref_mode", 0))
    for g in groups:
        for k in SCALARS[g]:
            out.append("#define TCOMP_%s (%d)\n" % (k.upper(), f[k]))
    out.append("\nstatic const char *const tcomp_sensor_names[%d] = {%s};\n"
               % (max(1, len(f["sensors"])), ", ".join('"%s"' % s for s in f["sensors"]) or "0"))
    for g in groups:
        for k in ARRAYS[g]:
            out.append(_array(k, f[k]))
    out.append("/* the binary table (same bytes as the .bin, CRC-32 included) */\n")
    out.append("static const uint8_t tcomp_table_bin[%d] = {\n" % len(ex.table))
    for i in range(0, len(ex.table), 16):
        out.append("    " + ", ".join("0x%02x" % b for b in ex.table[i:i + 16]) + ",\n")
    out.append("};\n")
    out.append(CODE)
    out.append("\n#endif /* %s */\n" % guard)
    return "".join(out)
