/* Millisecond tick: real on the box (SysTick), virtual on the native board. */
#ifndef HAL_TIME_H
#define HAL_TIME_H

#include <stdbool.h>
#include <stdint.h>

/* Milliseconds since power-up; wraps at 2^32 (compare with a signed difference). */
uint32_t hal_millis(void);

/* Sleep until something may have happened: an interrupt (received byte, tick) on the box, a
 * feed command or pty input on the native board. `wake_at_ms` is when the caller next has work
 * (the next sample instant); the native board advances its virtual clock there on a sample
 * feed. Returns false when the board wants the firmware to stop (native: end of feed). */
bool hal_wait_for_event(uint32_t wake_at_ms);

#endif
