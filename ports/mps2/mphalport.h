#include <stdint.h>
#include "py/mpconfig.h"

// Millisecond ticks from SysTick (main.c); microseconds from SysTick's down-counter.
extern volatile uint32_t mps2_ticks_ms;
static inline mp_uint_t mp_hal_ticks_ms(void) {
    return mps2_ticks_ms;
}
mp_uint_t mp_hal_ticks_us(void);
static inline mp_uint_t mp_hal_ticks_cpu(void) {
    return 0;
}
void mp_hal_delay_ms(mp_uint_t ms);
void mp_hal_delay_us(mp_uint_t us);
#include "shared/runtime/interrupt_char.h"
// No GPIO pin API (the board's pins are the rig's or a driver's Python objects).
#define mp_hal_pin_obj_t void *
