/* Internals shared by the native board's files (docs/native-board.md). */
#ifndef NATIVE_BOARD_H
#define NATIVE_BOARD_H

#include <stdbool.h>
#include <stdint.h>

#include "max31856_sim.h"

/* One simulated MAX31856 per chip select. */
max31856_sim_t *native_chip(uint8_t cs);
/* From the first `S` feed line on, chips at or beyond `count` are absent (read 0xFF). */
void native_set_chip_count(uint8_t count);

/* The next SPI transfer never completes (a locked-up bus): for the watchdog test. */
void native_spi_hang_once(void);

/* Pseudo-terminal UART: create one (inherited_fd < 0) or use the pty master the caller passed
 * down (--pty-fd), and print "PTY <slave path>"; false with a message on failure. */
bool native_uart_open(int inherited_fd);
/* File descriptor of the pty master, for polling. */
int native_uart_fd(void);

void native_set_aux0(int32_t value);
void native_set_reset_cause_watchdog(bool wdt);

/* --retain FILE: keep the retained memory (backup SRAM) in FILE across processes; false when
 * FILE cannot be opened. */
bool native_set_retain_file(const char *path);
void native_advance_time_to(uint32_t ms);

/* Exit status for main(): 0 after Q or end of feed, 2 after a bad feed line. */
int native_exit_status(void);

#endif
