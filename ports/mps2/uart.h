#ifndef MPS2_UART_H
#define MPS2_UART_H
#include <stddef.h>
#include <stdint.h>

// CMSDK APB UARTs of the mps2-an385: UART0 is the serial link and the REPL, UART1 the rig's
// control channel (QEMU connects each to a host character device with -serial).
#define MPS2_UART_COUNT (2)
void mps2_uart_init(int n, uint32_t baud);
int mps2_uart_rx_any(int n);
int mps2_uart_rx(int n);  // one byte, or -1 when none is waiting (never blocks)
void mps2_uart_tx(int n, const uint8_t *buf, size_t len);
#endif
