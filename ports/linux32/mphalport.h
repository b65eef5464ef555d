// HAL declarations of the linux32 port (mphal.c).
#include <stdint.h>
#include <unistd.h>
#include "shared/runtime/interrupt_char.h"
#ifndef CHAR_CTRL_C
#define CHAR_CTRL_C (3)
#endif
#ifndef CHAR_CTRL_D
#define CHAR_CTRL_D (4)
#endif
// no machine.Pin in C (the rig's machine module is Python): keep the core off extmod/virtpin.h
#define mp_hal_pin_obj_t void *
