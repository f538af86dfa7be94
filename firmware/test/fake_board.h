/* A fake board for application tests: every hal_*.h function, with control functions.
 * SPI goes to eight register-level MAX31856 models, the UART to memory buffers, time and the
 * reset cause are set by the test. */
#ifndef FAKE_BOARD_H
#define FAKE_BOARD_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "max31856_sim.h"

#define FAKE_N_CHIPS 8
#define FAKE_TX_SIZE 65536

extern max31856_sim_t fake_chips[FAKE_N_CHIPS];
extern uint32_t fake_now_ms;
extern int32_t fake_aux;
extern bool fake_aux_ok;
extern bool fake_reset_by_watchdog;
extern uint32_t fake_watchdog_timeout_ms; /* 0 until started */
extern uint32_t fake_watchdog_kicks;
extern uint32_t fake_board_inits;

void fake_board_reset(void);
/* Bytes the CNC side "sends" (read by hal_uart_read). */
void fake_uart_send(const char *s);
/* Everything the box wrote since the last take, NUL-terminated; clears the buffer. */
const char *fake_uart_take(void);

/* Retained memory: a power cut without backup battery (garbage, boots cold). */
void fake_retain_clear(void);
extern uint8_t fake_retained[4096];

#endif
