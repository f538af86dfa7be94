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

/* True if the last reset was warm: the watchdog, a software reset or a brown-out that did not
 * take the chip through a power-on reset. Only then may the application trust retained memory
 * (hal_retain.h); a power-on reset is cold even when a backup battery kept it. */
bool hal_reset_was_warm(void);

#endif
