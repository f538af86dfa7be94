/* Independent watchdog: resets the chip if the main loop stops kicking it. */
#ifndef HAL_WATCHDOG_H
#define HAL_WATCHDOG_H

#include <stdbool.h>
#include <stdint.h>

/* Start the watchdog with roughly this timeout; it cannot be stopped afterwards. */
void hal_watchdog_start(uint32_t timeout_ms);

/* Reload the watchdog counter. */
void hal_watchdog_kick(void);

/* True if the last reset was caused by the watchdog (read once at boot, then cleared). */
bool hal_reset_was_watchdog(void);

#endif
