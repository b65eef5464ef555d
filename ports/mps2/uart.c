#include "py/runtime.h"
#include "py/stream.h"
#include "py/mperrno.h"
#include "py/mphal.h"
#include "shared/runtime/interrupt_char.h"
#include "uart.h"

// CMSDK APB UART registers (ARM DDI 0479, "Cortex-M System Design Kit", UART)
typedef struct {
    volatile uint32_t data;
    volatile uint32_t state;     // bit 0: TX buffer full, bit 1: RX buffer full
    volatile uint32_t ctrl;      // bit 0: TX enable, bit 1: RX enable
    volatile uint32_t intstatus;
    volatile uint32_t bauddiv;
} cmsdk_uart_t;

#define UART_STATE_TXFULL (1)
#define UART_STATE_RXFULL (2)
#define UART_CTRL_TXEN (1)
#define UART_CTRL_RXEN (2)
#define MPS2_SYSCLK (25000000)

#define UART_CTRL_RXINTEN (8)
#define UART_INT_RX (2)
#define NVIC_ISER0 (*(volatile uint32_t *)0xe000e100)

static cmsdk_uart_t *const uarts[MPS2_UART_COUNT] = {
    (cmsdk_uart_t *)0x40004000, (cmsdk_uart_t *)0x40005000,
};

// A real UART driver fills a ring buffer from the receive interrupt (rxbuf= on other ports):
// QEMU's CMSDK UART holds one byte, so bytes arriving during a firmware cycle wait here.
#define RX_RING (1024)
typedef struct {
    volatile uint16_t head, tail;  // head: written by the interrupt, tail: by the reader
    uint8_t buf[RX_RING];
} rx_ring_t;
static rx_ring_t rings[MPS2_UART_COUNT];
static bool interrupt_char_on[MPS2_UART_COUNT] = {true, false};  // Ctrl-C on the REPL's UART only

static void uart_rx_irq(int n) {
    cmsdk_uart_t *u = uarts[n];
    rx_ring_t *r = &rings[n];
    // Clear the interrupt before reading: a byte that arrives after the last read raises it
    // again (cleared after the loop, that byte would sit in the UART with no interrupt pending).
    u->intstatus = UART_INT_RX;
    while (u->state & UART_STATE_RXFULL) {
        int c = u->data & 0xff;
        if (interrupt_char_on[n] && c == mp_interrupt_char) {
            mp_sched_keyboard_interrupt();
            continue;
        }
        uint16_t next = (r->head + 1) % RX_RING;
        if (next != r->tail) {  // full: drop, as a UART overrun does
            r->buf[r->head] = c;
            r->head = next;
        }
    }
}

void UART0RX_Handler(void) {
    uart_rx_irq(0);
}

void UART1RX_Handler(void) {
    uart_rx_irq(1);
}

void mps2_uart_init(int n, uint32_t baud) {
    uarts[n]->bauddiv = MPS2_SYSCLK / baud;
    uarts[n]->ctrl = UART_CTRL_TXEN | UART_CTRL_RXEN | UART_CTRL_RXINTEN;
    NVIC_ISER0 = 1u << (2 * n);  // UARTn RX is IRQ 2n on the AN385
}

int mps2_uart_rx_any(int n) {
    rx_ring_t *r = &rings[n];
    return (r->head - r->tail + RX_RING) % RX_RING;
}

int mps2_uart_rx(int n) {
    rx_ring_t *r = &rings[n];
    if (r->head == r->tail) {
        return -1;
    }
    int c = r->buf[r->tail];
    r->tail = (r->tail + 1) % RX_RING;
    return c;
}

void mps2_uart_tx(int n, const uint8_t *buf, size_t len) {
    cmsdk_uart_t *u = uarts[n];
    while (len--) {
        while (u->state & UART_STATE_TXFULL) {
        }
        u->data = *buf++;
    }
}

// ---- machine.UART: the board's stream (firmware/board.py: readinto never blocks, write(buf, n)) ----

typedef struct {
    mp_obj_base_t base;
    uint8_t id;
} machine_uart_obj_t;

static const machine_uart_obj_t machine_uart_objs[MPS2_UART_COUNT];

static mp_obj_t machine_uart_make_new(const mp_obj_type_t *type, size_t n_args, size_t n_kw, const mp_obj_t *args) {
    enum { ARG_id, ARG_baudrate };
    static const mp_arg_t allowed[] = {
        { MP_QSTR_id, MP_ARG_REQUIRED | MP_ARG_INT, {.u_int = 0} },
        { MP_QSTR_baudrate, MP_ARG_INT, {.u_int = 115200} },
    };
    mp_arg_val_t vals[MP_ARRAY_SIZE(allowed)];
    mp_map_t kw;
    mp_map_init_fixed_table(&kw, n_kw, args + n_args);
    // extra keywords of other ports (tx, rx, timeout, rxbuf) are accepted and ignored
    mp_arg_parse_all(n_args, args, &kw, MP_ARRAY_SIZE(allowed), allowed, vals);
    mp_int_t id = vals[ARG_id].u_int;
    if (id < 0 || id >= MPS2_UART_COUNT) {
        mp_raise_ValueError(MP_ERROR_TEXT("UART id"));
    }
    mps2_uart_init(id, vals[ARG_baudrate].u_int);
    return MP_OBJ_FROM_PTR(&machine_uart_objs[id]);
}

static mp_uint_t machine_uart_read(mp_obj_t self_in, void *buf, mp_uint_t size, int *errcode) {
    machine_uart_obj_t *self = MP_OBJ_TO_PTR(self_in);
    uint8_t *p = buf;
    mp_uint_t n = 0;
    while (n < size) {
        int c = mps2_uart_rx(self->id);
        if (c < 0) {
            break;
        }
        p[n++] = c;
    }
    if (n == 0 && size > 0) {
        *errcode = MP_EAGAIN;  // non-blocking: readinto returns None, read returns None
        return MP_STREAM_ERROR;
    }
    return n;
}

static mp_uint_t machine_uart_write(mp_obj_t self_in, const void *buf, mp_uint_t size, int *errcode) {
    machine_uart_obj_t *self = MP_OBJ_TO_PTR(self_in);
    mps2_uart_tx(self->id, buf, size);
    return size;
}

static mp_uint_t machine_uart_ioctl(mp_obj_t self_in, mp_uint_t request, uintptr_t arg, int *errcode) {
    machine_uart_obj_t *self = MP_OBJ_TO_PTR(self_in);
    if (request == MP_STREAM_POLL) {
        mp_uint_t ret = 0;
        if ((arg & MP_STREAM_POLL_RD) && mps2_uart_rx_any(self->id)) {
            ret |= MP_STREAM_POLL_RD;
        }
        if (arg & MP_STREAM_POLL_WR) {
            ret |= MP_STREAM_POLL_WR;
        }
        return ret;
    }
    if (request == MP_STREAM_FLUSH || request == MP_STREAM_CLOSE) {
        return 0;
    }
    *errcode = MP_EINVAL;
    return MP_STREAM_ERROR;
}

static mp_obj_t machine_uart_any(mp_obj_t self_in) {
    machine_uart_obj_t *self = MP_OBJ_TO_PTR(self_in);
    return MP_OBJ_NEW_SMALL_INT(mps2_uart_rx_any(self->id));
}
static MP_DEFINE_CONST_FUN_OBJ_1(machine_uart_any_obj, machine_uart_any);

static const mp_rom_map_elem_t machine_uart_locals_dict_table[] = {
    { MP_ROM_QSTR(MP_QSTR_any), MP_ROM_PTR(&machine_uart_any_obj) },
    { MP_ROM_QSTR(MP_QSTR_read), MP_ROM_PTR(&mp_stream_read_obj) },
    { MP_ROM_QSTR(MP_QSTR_readinto), MP_ROM_PTR(&mp_stream_readinto_obj) },
    { MP_ROM_QSTR(MP_QSTR_write), MP_ROM_PTR(&mp_stream_write_obj) },
};
static MP_DEFINE_CONST_DICT(machine_uart_locals_dict, machine_uart_locals_dict_table);

static const mp_stream_p_t machine_uart_stream_p = {
    .read = machine_uart_read,
    .write = machine_uart_write,
    .ioctl = machine_uart_ioctl,
    .is_text = false,
};

MP_DEFINE_CONST_OBJ_TYPE(
    machine_uart_type,
    MP_QSTR_UART,
    MP_TYPE_FLAG_ITER_IS_STREAM,
    make_new, machine_uart_make_new,
    protocol, &machine_uart_stream_p,
    locals_dict, &machine_uart_locals_dict
    );

static const machine_uart_obj_t machine_uart_objs[MPS2_UART_COUNT] = {
    {{&machine_uart_type}, 0}, {{&machine_uart_type}, 1},
};
