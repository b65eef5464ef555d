// The port's HAL: stdin/stdout on file descriptors 0/1 (a pty in the rig), stderr on 2,
// monotonic ticks and sleeps on the Linux clocks.
#include <errno.h>
#include <poll.h>
#include <time.h>
#include <unistd.h>

#include "py/mphal.h"
#include "py/mpprint.h"
#include "py/stream.h"
#include "py/runtime.h"
#include "shared/runtime/interrupt_char.h"

int mp_hal_stdin_rx_chr(void) {
    unsigned char c;
    for (;;) {
        ssize_t n = read(0, &c, 1);
        if (n == 1) {
            return c;
        }
        if (n == 0) {
            return CHAR_CTRL_D;  // end of input ends the REPL
        }
        if (errno != EINTR) {
            return CHAR_CTRL_D;
        }
    }
}

static void write_all(int fd, const char *str, size_t len) {
    while (len > 0) {
        ssize_t n = write(fd, str, len);
        if (n < 0) {
            if (errno == EINTR || errno == EAGAIN) {
                continue;
            }
            return;
        }
        str += n;
        len -= n;
    }
}

mp_uint_t mp_hal_stdout_tx_strn(const char *str, size_t len) {
    write_all(1, str, len);
    return len;
}

static void stderr_print_strn(void *env, const char *str, size_t len) {
    (void)env;
    write_all(2, str, len);
}

const mp_print_t mp_stderr_print = {NULL, stderr_print_strn};

uintptr_t mp_hal_stdio_poll(uintptr_t poll_flags) {
    struct pollfd p = {0, POLLIN, 0};
    uintptr_t ret = 0;
    if ((poll_flags & MP_STREAM_POLL_RD) && poll(&p, 1, 0) > 0 && (p.revents & POLLIN)) {
        ret |= MP_STREAM_POLL_RD;
    }
    return ret | (poll_flags & MP_STREAM_POLL_WR);
}

static uint64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + ts.tv_nsec;
}

mp_uint_t mp_hal_ticks_ms(void) {
    return now_ns() / 1000000u;
}

mp_uint_t mp_hal_ticks_us(void) {
    return now_ns() / 1000u;
}

mp_uint_t mp_hal_ticks_cpu(void) {
    return now_ns();
}

uint64_t mp_hal_time_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + ts.tv_nsec;
}

void mp_hal_delay_us(mp_uint_t us) {
    struct timespec ts = {us / 1000000u, (us % 1000000u) * 1000u};
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {
        mp_handle_pending(true);
    }
}

void mp_hal_delay_ms(mp_uint_t ms) {
    uint64_t end = now_ns() + (uint64_t)ms * 1000000u;
    for (;;) {
        mp_handle_pending(true);
        uint64_t t = now_ns();
        if (t >= end) {
            return;
        }
        uint64_t left_us = (end - t) / 1000u;
        mp_hal_delay_us(left_us > 10000 ? 10000 : (left_us ? left_us : 1));
    }
}
