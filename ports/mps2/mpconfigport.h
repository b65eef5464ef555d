// MicroPython configuration of the tcomp board image for QEMU's mps2-an385 (Cortex-M3).
// Core features only, plus what the firmware and the HIL rig's simulation need:
// long ints (CRC-32, SHA-256, 2^30 limits), floats (the chip simulators; the firmware's
// cycle uses none), struct/array/collections, heap_lock, and .mpy loading in place from
// the image's ROM table (MICROPY_VFS_ROM without the vfs: the "frozen" firmware).
#include <stdint.h>

#define MICROPY_CONFIG_ROM_LEVEL (MICROPY_CONFIG_ROM_LEVEL_CORE_FEATURES)

#define MICROPY_ENABLE_COMPILER (1)
#define MICROPY_ENABLE_GC (1)
#define MICROPY_HELPER_REPL (1)
#define MICROPY_REPL_AUTO_INDENT (1)
#define MICROPY_KBD_EXCEPTION (1)
#define MICROPY_LONGINT_IMPL (MICROPY_LONGINT_IMPL_MPZ)
#define MICROPY_FLOAT_IMPL (MICROPY_FLOAT_IMPL_DOUBLE)
#define MICROPY_ERROR_REPORTING (MICROPY_ERROR_REPORTING_NORMAL)
#define MICROPY_ENABLE_SOURCE_LINE (1)
#define MICROPY_STACK_CHECK (1)
#define MICROPY_ENABLE_EMERGENCY_EXCEPTION_BUF (1)
#define MICROPY_EMERGENCY_EXCEPTION_BUF_SIZE (256)
#define MICROPY_MODULE_WEAK_LINKS (0)
#define MICROPY_CAN_OVERRIDE_BUILTINS (0)
#define MICROPY_PY_BUILTINS_HELP (0)
#define MICROPY_PY_BUILTINS_INPUT (0)
#define MICROPY_PY_BUILTINS_BYTEARRAY (1)
#define MICROPY_PY_BUILTINS_MEMORYVIEW (1)
#define MICROPY_PY_BUILTINS_SET (1)
#define MICROPY_PY_BUILTINS_SLICE (1)
#define MICROPY_PY_BUILTINS_FROZENSET (1)
#define MICROPY_PY_BUILTINS_PROPERTY (1)
#define MICROPY_PY_BUILTINS_ENUMERATE (1)
#define MICROPY_PY_BUILTINS_REVERSED (1)
#define MICROPY_PY_BUILTINS_MIN_MAX (1)
#define MICROPY_PY_BUILTINS_STR_UNICODE (0)
#define MICROPY_PY_BUILTINS_STR_SPLITLINES (1)
#define MICROPY_PY_BUILTINS_ROUND_INT (1)
#define MICROPY_PY_BUILTINS_RANGE_ATTRS (1)
#define MICROPY_PY_ALL_SPECIAL_METHODS (1)
#define MICROPY_PY_REVERSE_SPECIAL_METHODS (1)
#define MICROPY_PY___FILE__ (1)
#define MICROPY_PY_GC (1)
#define MICROPY_PY_ARRAY (1)
#define MICROPY_PY_ARRAY_SLICE_ASSIGN (1)
#define MICROPY_PY_COLLECTIONS (1)
#define MICROPY_PY_COLLECTIONS_ORDEREDDICT (1)
#define MICROPY_PY_MATH (1)
#define MICROPY_PY_STRUCT (1)
#define MICROPY_PY_SYS (1)
#define MICROPY_PY_SYS_MODULES (1)
#define MICROPY_PY_SYS_EXIT (1)
#define MICROPY_PY_SYS_PATH (1)
#define MICROPY_PY_SYS_ARGV (1)
#define MICROPY_PY_SYS_STDFILES (1)
#define MICROPY_PY_SYS_STDIO_BUFFER (1)
#define MICROPY_PY_SYS_PLATFORM "mps2"
#define MICROPY_PY_IO (1)
#define MICROPY_STREAMS_NON_BLOCK (1)  // UART readinto: None when nothing waits
#define MICROPY_PY_MICROPYTHON (1)
#define MICROPY_PY_MICROPYTHON_MEM_INFO (1)
#define MICROPY_PY_MICROPYTHON_HEAP_LOCKED (1)
#define MICROPY_PY_ERRNO (1)
#define MICROPY_PY_OS (0)
#define MICROPY_PY_TIME (0)

// .mpy files: from the ROM table (bytecode runs in place) or from the host's files (semihosting)
#define MICROPY_PERSISTENT_CODE_LOAD (1)
#define MICROPY_VFS_ROM (1)
#define MICROPY_VFS_ROM_IOCTL (0)
#define MICROPY_HAS_FILE_READER (1)
#define MICROPY_READER_VFS (0)
#define MICROPY_READER_POSIX (0)
#define MICROPY_ENABLE_EXTERNAL_IMPORT (1)
#define MICROPY_MODULE_FROZEN (0)

#define MICROPY_ALLOC_PATH_MAX (128)
#define MICROPY_GC_ALLOC_THRESHOLD (0)

#define MICROPY_HW_BOARD_NAME "tcomp mps2-an385 (QEMU)"
#define MICROPY_HW_MCU_NAME "Cortex-M3"

typedef long mp_off_t;

#define MICROPY_HEAP_SIZE_MAX (512 * 1024)

// The rig image (make VARIANT=rig: firmware-rig.elf, the test bench of `tcomp hil --interpreter qemu`)
// runs the same frozen firmware on a core built for speed; firmware.elf, whose instructions and heap
// the benches measure, keeps the plain core. Neither option changes what a program computes:
// - function frames on a Python stack, not the heap: on the plain core every call of a function with
//   more than 11 words of state allocates its frame on the GC heap (and frees it), and gc_alloc scans
//   the heap's fragmented start for room each time (41-51 % of the rig's instructions, docs/hil.md);
// - the VM options of the MCU ports at the extra-features level (rp2, stm32): cached map lookups,
//   the attribute fast path, computed-goto dispatch.
#ifdef MPS2_RIG_IMAGE
#define MICROPY_ENABLE_PYSTACK (1)
#define MPS2_PYSTACK_SIZE (16 * 1024)
#ifndef MPS2_NO_COMPUTED_GOTO
#define MICROPY_OPT_COMPUTED_GOTO (1)
#endif
#define MICROPY_OPT_MAP_LOOKUP_CACHE (1)
#define MICROPY_OPT_LOAD_ATTR_FAST_PATH (1)
#endif

#define MP_STATE_PORT MP_STATE_VM

#include <alloca.h>
