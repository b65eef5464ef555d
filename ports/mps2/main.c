// tcomp board image for QEMU's mps2-an385: MicroPython with the firmware in ROM.
//
// The semihosting command line (QEMU -append) chooses what runs:
//   heap=N         GC heap in bytes (K suffix allowed; default 64K, at most MICROPY_HEAP_SIZE_MAX)
//   -c CODE        run CODE (the rest of the line), then exit QEMU with its status
//                  (SystemExit(n): n; an uncaught exception: traceback on stderr, status 1)
//   (nothing)      the REPL on UART0, friendly and raw (mpremote), with soft reset
#include <string.h>
#include <stdlib.h>
#include "py/compile.h"
#include "py/runtime.h"
#include "py/gc.h"
#include "py/mperrno.h"
#include "py/cstack.h"
#include "py/stream.h"
#include "py/mphal.h"
#include "shared/runtime/gchelper.h"
#include "shared/runtime/pyexec.h"
#include "semihost.h"
#include "uart.h"

volatile uint32_t mps2_ticks_ms;

#define SYST_RVR (*(volatile uint32_t *)0xe000e014)
#define SYST_CVR (*(volatile uint32_t *)0xe000e018)
#define SYST_CSR (*(volatile uint32_t *)0xe000e010)

void SysTick_Handler(void) {
    mps2_ticks_ms++;
}

mp_uint_t mp_hal_ticks_us(void) {
    uint32_t ms, cvr;
    do {
        ms = mps2_ticks_ms;
        cvr = SYST_CVR;
    } while (ms != mps2_ticks_ms || (SYST_CSR & (1 << 16)));
    return ms * 1000 + (SYST_RVR - cvr) / 25;
}

void mp_hal_delay_ms(mp_uint_t ms) {
    uint32_t start = mps2_ticks_ms;
    while (mps2_ticks_ms - start < ms) {
        mp_handle_pending(true);
        __asm__ volatile ("wfi");
    }
}

void mp_hal_delay_us(mp_uint_t us) {
    uint32_t start = mp_hal_ticks_us();
    while (mp_hal_ticks_us() - start < us) {
    }
}

// ---- console: UART0 (stdin/stdout, the REPL), the host's stderr (sys.stderr, tracebacks) ----

int mp_hal_stdin_rx_chr(void) {
    for (;;) {
        int c = mps2_uart_rx(0);
        if (c >= 0) {
            return c;
        }
        mp_handle_pending(true);
        __asm__ volatile ("wfi");
    }
}

mp_uint_t mp_hal_stdout_tx_strn(const char *str, size_t len) {
    mps2_uart_tx(0, (const uint8_t *)str, len);
    return len;
}

uintptr_t mp_hal_stdio_poll(uintptr_t poll_flags) {
    uintptr_t ret = 0;
    if ((poll_flags & MP_STREAM_POLL_RD) && mps2_uart_rx_any(0)) {
        ret |= MP_STREAM_POLL_RD;
    }
    return ret | (poll_flags & MP_STREAM_POLL_WR);
}

static void stderr_strn(void *env, const char *str, size_t len) {
    (void)env;
    sh_stderr(str, len);
}
static const mp_print_t stderr_print = {NULL, stderr_strn};

typedef struct {
    mp_obj_base_t base;
    int fd;
} stdio_obj_t;

static mp_uint_t stdio_read(mp_obj_t self_in, void *buf, mp_uint_t size, int *errcode) {
    uint8_t *p = buf;
    for (mp_uint_t i = 0; i < size; i++) {
        int c = mp_hal_stdin_rx_chr();
        p[i] = c == '\r' ? '\n' : c;
    }
    return size;
}

static mp_uint_t stdio_write(mp_obj_t self_in, const void *buf, mp_uint_t size, int *errcode) {
    stdio_obj_t *self = MP_OBJ_TO_PTR(self_in);
    if (self->fd == 2) {
        sh_stderr(buf, size);
    } else {
        mp_hal_stdout_tx_strn_cooked(buf, size);
    }
    return size;
}

static mp_uint_t stdio_ioctl(mp_obj_t self_in, mp_uint_t request, uintptr_t arg, int *errcode) {
    if (request == MP_STREAM_POLL) {
        return mp_hal_stdio_poll(arg);
    }
    if (request == MP_STREAM_FLUSH || request == MP_STREAM_CLOSE) {
        return 0;
    }
    *errcode = MP_EINVAL;
    return MP_STREAM_ERROR;
}

static const mp_rom_map_elem_t stdio_locals_dict_table[] = {
    { MP_ROM_QSTR(MP_QSTR_read), MP_ROM_PTR(&mp_stream_read_obj) },
    { MP_ROM_QSTR(MP_QSTR_readinto), MP_ROM_PTR(&mp_stream_readinto_obj) },
    { MP_ROM_QSTR(MP_QSTR_readline), MP_ROM_PTR(&mp_stream_unbuffered_readline_obj) },
    { MP_ROM_QSTR(MP_QSTR_write), MP_ROM_PTR(&mp_stream_write_obj) },
    { MP_ROM_QSTR(MP_QSTR_flush), MP_ROM_PTR(&mp_stream_flush_obj) },
};
static MP_DEFINE_CONST_DICT(stdio_locals_dict, stdio_locals_dict_table);

static const mp_stream_p_t stdio_stream_p = {
    .read = stdio_read,
    .write = stdio_write,
    .ioctl = stdio_ioctl,
    .is_text = true,
};

MP_DEFINE_CONST_OBJ_TYPE(stdio_type, MP_QSTR_FileIO, MP_TYPE_FLAG_ITER_IS_STREAM,
    protocol, &stdio_stream_p, locals_dict, &stdio_locals_dict);

const stdio_obj_t mp_sys_stdin_obj = {{&stdio_type}, 0};
const stdio_obj_t mp_sys_stdout_obj = {{&stdio_type}, 1};
const stdio_obj_t mp_sys_stderr_obj = {{&stdio_type}, 2};

// ---- runtime glue ----------------------------------------------------------------------------

static uint8_t heap[MICROPY_HEAP_SIZE_MAX] __attribute__((aligned(8)));
#if MICROPY_ENABLE_PYSTACK
static uint8_t pystack[MPS2_PYSTACK_SIZE] __attribute__((aligned(8)));
#endif

void gc_collect(void) {
    gc_collect_start();
    gc_helper_collect_regs_and_stack();
    gc_collect_end();
}

void mps2_fatal(const char *msg) {
    sh_stderr(msg, strlen(msg));
    sh_exit(99);
}

void nlr_jump_fail(void *val) {
    mps2_fatal("FATAL: uncaught NLR\n");
    for (;;) {
    }
}

void MP_NORETURN __fatal_error(const char *msg) {
    mps2_fatal(msg);
    for (;;) {
    }
}

#ifndef NDEBUG
void MP_WEAK __assert_func(const char *file, int line, const char *func, const char *expr) {
    mp_printf(&stderr_print, "Assertion '%s' failed, at file %s:%d\n", expr, file, line);
    mps2_fatal("assert\n");
}
#endif

// ---- main ------------------------------------------------------------------------------------

static char cmdline[2048];

static size_t parse_size(const char *s) {
    char *end;
    size_t n = strtoul(s, &end, 10);
    if (*end == 'K' || *end == 'k') {
        n *= 1024;
    }
    return n;
}

static int run_code(const char *code) {
    nlr_buf_t nlr;
    if (nlr_push(&nlr) == 0) {
        mp_lexer_t *lex = mp_lexer_new_from_str_len(MP_QSTR__lt_stdin_gt_, code, strlen(code), 0);
        qstr source_name = lex->source_name;
        mp_parse_tree_t parse_tree = mp_parse(lex, MP_PARSE_FILE_INPUT);
        mp_obj_t module_fun = mp_compile(&parse_tree, source_name, false);
        mp_call_function_0(module_fun);
        nlr_pop();
        return 0;
    }
    mp_obj_t exc = MP_OBJ_FROM_PTR(nlr.ret_val);
    if (mp_obj_is_subclass_fast(MP_OBJ_FROM_PTR(mp_obj_get_type(exc)), MP_OBJ_FROM_PTR(&mp_type_SystemExit))) {
        mp_obj_t val = mp_obj_exception_get_value(exc);
        if (val == mp_const_none) {
            return 0;
        }
        mp_int_t code_val;
        return mp_obj_get_int_maybe(val, &code_val) ? (int)code_val : 1;
    }
    mp_obj_print_exception(&stderr_print, exc);
    return 1;
}

int main(void) {
    mps2_uart_init(0, 115200);
    mps2_uart_init(1, 115200);

    size_t heap_size = 64 * 1024;
    const char *code = NULL;
    int n = sh_cmdline(cmdline, sizeof(cmdline) - 1);
    if (n > 0) {
        cmdline[n] = 0;
        char *p = strchr(cmdline, ' ');  // skip the kernel's file name
        while (p != NULL && *p) {
            while (*p == ' ') {
                p++;
            }
            if (strncmp(p, "heap=", 5) == 0) {
                heap_size = parse_size(p + 5);
            } else if (strncmp(p, "-c ", 3) == 0) {
                code = p + 3;
                break;
            }
            p = strchr(p, ' ');
        }
    }
    if (heap_size > sizeof(heap) || heap_size < 4096) {
        mps2_fatal("heap= out of range\n");
    }

soft_reset:
    extern uint32_t _estack;
    mp_cstack_init_with_top(&_estack, 30 * 1024);
    gc_init(heap, heap + heap_size);
    #if MICROPY_ENABLE_PYSTACK
    mp_pystack_init(pystack, pystack + sizeof(pystack));
    #endif
    mp_init();
    mp_obj_list_append(mp_sys_path, MP_OBJ_NEW_QSTR(MP_QSTR_));

    if (code != NULL) {
        mp_hal_set_interrupt_char(-1);
        int status = run_code(code);
        gc_sweep_all();
        sh_exit(status);
    }

    for (;;) {
        if (pyexec_mode_kind == PYEXEC_MODE_RAW_REPL) {
            if (pyexec_raw_repl() != 0) {
                break;
            }
        } else {
            if (pyexec_friendly_repl() != 0) {
                break;
            }
        }
    }
    mp_printf(&mp_plat_print, "MPY: soft reboot\n");
    gc_sweep_all();
    mp_deinit();
    goto soft_reset;
}
