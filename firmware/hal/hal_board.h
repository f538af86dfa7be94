/* Board bring-up: clocks, pins and peripherals behind the other hal_*.h functions. */
#ifndef HAL_BOARD_H
#define HAL_BOARD_H

/* Called once at boot before any other HAL function. */
void hal_board_init(void);

#endif
