/* Board bring-up: clocks, pins and peripherals behind the other hal_*.h functions. */
#ifndef HAL_BOARD_H
#define HAL_BOARD_H

/* Called once at boot before any other HAL function. */
void hal_board_init(void);

/* The entry point a board's start-up code calls once RAM is ready (the STM32's Reset_Handler,
 * the native main() after its options). The application defines it (src/app.c): boot, then
 * sample and answer until the board's hal_wait_for_event says stop, which only the native
 * board's feed does. Declared here, in the HAL contract, so that a board needs nothing of the
 * application's headers. */
int app_main(void);

#endif
