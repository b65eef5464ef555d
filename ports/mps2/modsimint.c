// simint.muldiv: exact floor(((a * b) << shift + add) / d) on up to 64-bit operands, for the HIL
// rig's chip simulators running on this image (hil_tests/sim/intmath.py). Their conversions
// multiply micro-ohms by 2**15..2**30 scales; on a 32-bit MicroPython those intermediates are
// heap-allocated long ints, and the simulators run inside the firmware's heap-locked cycle.
// A real chip does this arithmetic in silicon: here it is 128-bit C, allocation-free whenever
// the result is a small int. Not used by the firmware.
#include "py/runtime.h"
#include "py/objint.h"
#include "py/smallint.h"

static uint64_t get_u64(mp_obj_t o) {
    if (mp_obj_is_small_int(o)) {
        mp_int_t v = MP_OBJ_SMALL_INT_VALUE(o);
        if (v < 0) {
            mp_raise_ValueError(MP_ERROR_TEXT("negative"));
        }
        return v;
    }
    uint8_t b[8];
    mp_obj_int_to_bytes(o, sizeof(b), b, false, false, true);
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--) {
        v = (v << 8) | b[i];
    }
    return v;
}

typedef struct {
    uint64_t hi, lo;
} u128_t;

static u128_t mul64(uint64_t a, uint64_t b) {
    uint64_t a0 = (uint32_t)a, a1 = a >> 32, b0 = (uint32_t)b, b1 = b >> 32;
    uint64_t p00 = a0 * b0, p01 = a0 * b1, p10 = a1 * b0, p11 = a1 * b1;
    uint64_t mid = (p00 >> 32) + (uint32_t)p01 + (uint32_t)p10;
    u128_t r;
    r.lo = (mid << 32) | (uint32_t)p00;
    r.hi = p11 + (p01 >> 32) + (p10 >> 32) + (mid >> 32);
    return r;
}

static mp_obj_t simint_muldiv(size_t n_args, const mp_obj_t *args) {
    u128_t x = mul64(get_u64(args[0]), get_u64(args[1]));
    uint64_t d = get_u64(args[2]);
    uint64_t add = n_args > 3 ? get_u64(args[3]) : 0;
    mp_int_t shift = n_args > 4 ? mp_obj_get_int(args[4]) : 0;
    if (d == 0) {
        mp_raise_msg(&mp_type_ZeroDivisionError, MP_ERROR_TEXT("divide by zero"));
    }
    if (shift < 0 || shift > 63 || (shift && (x.hi >> (64 - shift)))) {
        mp_raise_msg(&mp_type_OverflowError, MP_ERROR_TEXT("muldiv"));
    }
    if (shift) {
        x.hi = (x.hi << shift) | (x.lo >> (64 - shift));
        x.lo <<= shift;
    }
    uint64_t lo = x.lo + add;
    x.hi += lo < x.lo;
    x.lo = lo;
    // 128 / 64 by shift and subtract
    uint64_t q_hi = 0, q_lo = 0, rem = 0;
    for (int i = 127; i >= 0; i--) {
        uint64_t top = rem >> 63;
        rem = (rem << 1) | (i >= 64 ? (x.hi >> (i - 64)) & 1 : (x.lo >> i) & 1);
        if (top || rem >= d) {
            rem -= d;
            if (i >= 64) {
                q_hi |= 1ull << (i - 64);
            } else {
                q_lo |= 1ull << i;
            }
        }
    }
    if (q_hi) {
        mp_raise_msg(&mp_type_OverflowError, MP_ERROR_TEXT("muldiv"));
    }
    if (q_lo <= (uint64_t)MP_SMALL_INT_MAX) {
        return MP_OBJ_NEW_SMALL_INT((mp_int_t)q_lo);
    }
    return mp_obj_new_int_from_ull(q_lo);
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(simint_muldiv_obj, 3, 5, simint_muldiv);

static const mp_rom_map_elem_t simint_module_globals_table[] = {
    { MP_ROM_QSTR(MP_QSTR___name__), MP_ROM_QSTR(MP_QSTR_simint) },
    { MP_ROM_QSTR(MP_QSTR_muldiv), MP_ROM_PTR(&simint_muldiv_obj) },
};
static MP_DEFINE_CONST_DICT(simint_module_globals, simint_module_globals_table);

const mp_obj_module_t mp_module_simint = {
    .base = { &mp_type_module },
    .globals = (mp_obj_dict_t *)&simint_module_globals,
};
MP_REGISTER_MODULE(MP_QSTR_simint, mp_module_simint);
