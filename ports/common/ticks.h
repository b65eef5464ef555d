// MicroPython's ticks API and the ms/us sleeps, shared by our ports (included by each port's time
// module, which adds what differs: time(), sleep(), ticks_cpu). The counters wrap at
// MICROPY_PY_TIME_TICKS_PERIOD: 2**30 on a 32-bit port, as on an MCU, so the firmware's wrap
// handling is exercised. The port supplies mp_hal_ticks_ms/us and mp_hal_delay_ms/us.
#ifndef TCOMP_PORTS_COMMON_TICKS_H
#define TCOMP_PORTS_COMMON_TICKS_H

#include "py/mphal.h"
#include "py/runtime.h"
#include "py/smallint.h"

#define TICKS_PERIOD (MICROPY_PY_TIME_TICKS_PERIOD)
#define TICKS_MAX (TICKS_PERIOD - 1)
#define TICKS_HALF (TICKS_PERIOD / 2)

static mp_obj_t time_ticks_ms(void) {
    return MP_OBJ_NEW_SMALL_INT(mp_hal_ticks_ms() & TICKS_MAX);
}
static MP_DEFINE_CONST_FUN_OBJ_0(time_ticks_ms_obj, time_ticks_ms);

static mp_obj_t time_ticks_us(void) {
    return MP_OBJ_NEW_SMALL_INT(mp_hal_ticks_us() & TICKS_MAX);
}
static MP_DEFINE_CONST_FUN_OBJ_0(time_ticks_us_obj, time_ticks_us);

// mp_obj_get_int_truncated: a non-int argument raises TypeError instead of being read as garbage
static mp_obj_t time_ticks_diff(mp_obj_t end_in, mp_obj_t start_in) {
    mp_uint_t diff = (mp_obj_get_int_truncated(end_in) - mp_obj_get_int_truncated(start_in) + TICKS_HALF) & TICKS_MAX;
    return MP_OBJ_NEW_SMALL_INT((mp_int_t)diff - TICKS_HALF);
}
static MP_DEFINE_CONST_FUN_OBJ_2(time_ticks_diff_obj, time_ticks_diff);

static mp_obj_t time_ticks_add(mp_obj_t ticks_in, mp_obj_t delta_in) {
    mp_int_t delta = mp_obj_get_int(delta_in);
    if (delta >= TICKS_HALF || delta < -TICKS_HALF) {
        mp_raise_msg(&mp_type_OverflowError, MP_ERROR_TEXT("ticks interval overflow"));
    }
    return MP_OBJ_NEW_SMALL_INT((mp_obj_get_int_truncated(ticks_in) + delta) & TICKS_MAX);
}
static MP_DEFINE_CONST_FUN_OBJ_2(time_ticks_add_obj, time_ticks_add);

static mp_obj_t time_sleep_ms(mp_obj_t ms) {
    mp_int_t v = mp_obj_get_int(ms);
    if (v > 0) {
        mp_hal_delay_ms(v);
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_1(time_sleep_ms_obj, time_sleep_ms);

static mp_obj_t time_sleep_us(mp_obj_t us) {
    mp_int_t v = mp_obj_get_int(us);
    if (v > 0) {
        mp_hal_delay_us(v);
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_1(time_sleep_us_obj, time_sleep_us);

#endif
