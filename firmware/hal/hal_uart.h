/* The serial line to the CNC (115200 8N1 on the box, a pseudo-terminal on the native board). */
#ifndef HAL_UART_H
#define HAL_UART_H

#include <stddef.h>
#include <stdint.h>

/* Queue bytes for transmission; waits while the transmit buffer is full, never drops. */
void hal_uart_write(const uint8_t *data, size_t len);

/* Copy up to max received bytes into buf without waiting; returns how many were copied. */
size_t hal_uart_read(uint8_t *buf, size_t max);

#endif
