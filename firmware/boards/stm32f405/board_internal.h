/* Functions shared between the STM32F405 board files (not part of the HAL). */
#ifndef BOARD_INTERNAL_H
#define BOARD_INTERNAL_H

#include <stdbool.h>
#include <stdint.h>

bool board_wait_set(volatile uint32_t *reg, uint32_t mask, uint32_t tries);
void board_pin_mode(uint32_t gpio_base, unsigned pin, uint32_t mode, uint32_t af);
void board_uart_init(void);
/* True while USART1 has received bytes the main loop has not read yet (a board that sleeps
 * without a periodic tick must not WFI on them: no further interrupt would wake it). */
bool board_uart_rx_pending(void);
void board_spi_init(void);
void board_adc_init(void);
void board_watchdog_read_reset_cause(void);

/* Interrupt handlers (vector table in startup.c). */
void SysTick_Handler(void);
void USART1_IRQHandler(void);

#endif
