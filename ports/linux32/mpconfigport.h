// tcomp's 32-bit Linux port of MicroPython: the MicroPython core (py/) built with -m32, so
// machine words, small ints (31 bits: they stop at 2**30) and heap objects are the size they
// are on a 32-bit MCU. Only what the firmware, the HIL rig and mpremote need is here.
#include <stdint.h>
#include <alloca.h>

// The same feature level as the rp2 port (an MCU port with the full core).
#define MICROPY_CONFIG_ROM_LEVEL            (MICROPY_CONFIG_ROM_LEVEL_EXTRA_FEATURES)

#define MICROPY_ENABLE_GC                   (1)
#define MICROPY_ENABLE_FINALISER            (1)
#define MICROPY_LONGINT_IMPL                (MICROPY_LONGINT_IMPL_MPZ)
// double, as the unix port: the simulated chips in the rig compute resistances in floats;
// the firmware's cycle is integer-only whatever the float width
#define MICROPY_FLOAT_IMPL                  (MICROPY_FLOAT_IMPL_DOUBLE)
#define MICROPY_READER_POSIX                (1)
#define MICROPY_HELPER_LEXER_UNIX           (1)
#define MICROPY_ALLOC_PATH_MAX              (4096)
#define MICROPY_USE_READLINE                (1)
#define MICROPY_HAL_HAS_VT100               (1)
#define MICROPY_KBD_EXCEPTION               (1)
#define MICROPY_MODULE_OVERRIDE_MAIN_IMPORT (1)
#define MICROPY_PY_SYS_PATH_ARGV_DEFAULTS   (0)
#define MICROPY_PY_SYS_PLATFORM             "linux"
#define MICROPY_PY_SYS_EXIT                 (1)
#define MICROPY_PY_SYS_STDFILES             (1)
#define MICROPY_PY_SYS_STDIO_BUFFER         (1)
#define MICROPY_PYEXEC_ENABLE_EXIT_CODE_HANDLING (1)
#define MICROPY_PY_MICROPYTHON_HEAP_LOCKED  (1)
// tracebacks of exceptions raised under heap_lock (a MemoryError in the cycle names its line)
#define MICROPY_ENABLE_EMERGENCY_EXCEPTION_BUF (1)
#define MICROPY_EMERGENCY_EXCEPTION_BUF_SIZE (512)
#define MICROPY_EPOCH_IS_1970               (1)
#define MICROPY_PERSISTENT_CODE_LOAD        (1)
#define MICROPY_EMIT_X86                    (0)  // bytecode only, as the .mpy files we load
#define MICROPY_PY_UCTYPES                  (0)  // extmod, not in the sdist
#define MICROPY_BANNER_MACHINE              "linux32 (tcomp)"
#define MICROPY_HW_BOARD_NAME               "linux32"
#define MICROPY_HW_MCU_NAME                 "i386"

extern const struct _mp_print_t mp_stderr_print;
#define MICROPY_ERROR_PRINTER               (&mp_stderr_print)

typedef int32_t mp_int_t;
typedef uint32_t mp_uint_t;
typedef long mp_off_t;

#define MP_STATE_PORT MP_STATE_VM
