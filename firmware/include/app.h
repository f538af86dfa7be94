/* The box application: sampling schedule, fault handling, model evaluation, output
 * conditioning and the serial protocol. Talks to hardware only through hal/hal_*.h. */
#ifndef APP_H
#define APP_H

#include <stdint.h>

/* Boot: read the reset cause, check the model CRC, configure the chips, start the watchdog. */
void app_init(void);

/* One pass of the main loop: kick the watchdog, answer received commands, take the sample if
 * it is due. Never waits. */
void app_poll(void);

/* Tick (ms) at which the next sample is due. */
uint32_t app_next_sample_ms(void);

/* app_main (declared in hal/hal_board.h, the entry the boards call): app_init, then app_poll
 * after every hal_wait_for_event until the board says stop. */

#endif
