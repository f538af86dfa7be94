/* STM32F405 board bring-up: 168 MHz from the internal oscillator, pins, SysTick, sleep.
 *
 * Pin map: USART1 TX/RX = PA9/PA10 (AF7); SPI1 SCK/MISO/MOSI = PA5/PA6/PA7 (AF5);
 * MAX31856 chip selects CS0..CS7 = PC0..PC7 (push-pull, idle high); spindle-speed input
 * = PA0 (ADC1_IN0). */
#include <stdbool.h>
#include <stdint.h>

#include "board_internal.h"
#include "hal_board.h"
#include "hal_time.h"
#include "stm32f405_regs.h"

/* Bounded waits: a flag that never comes (a broken clock, or QEMU, which does not model the
 * RCC) must not hang the boot; the watchdog and the status bits deal with what follows. */
bool board_wait_set(volatile uint32_t *reg, uint32_t mask, uint32_t tries)
{
    while (tries-- > 0u) {
        if ((*reg & mask) == mask) {
            return true;
        }
    }
    return false;
}

static void clock_init(void)
{
    RCC_APB1ENR |= RCC_APB1ENR_PWR;
    PWR_CR |= PWR_CR_VOS; /* voltage scale 1, required for 168 MHz */
    FLASH_ACR = FLASH_ACR_LATENCY_5WS | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
    /* HSI 16 MHz / M 16 = 1 MHz; x N 336 = 336 MHz VCO; / P 2 = 168 MHz; / Q 7 = 48 MHz.
     * HSI (1 % accuracy) instead of a crystal: the box has no USB and its sample clock only
     * needs to be close to the training data's period. */
    RCC_PLLCFGR = RCC_PLLCFGR_M(16) | RCC_PLLCFGR_N(336) | RCC_PLLCFGR_P_DIV2 |
                  RCC_PLLCFGR_SRC_HSI | RCC_PLLCFGR_Q(7);
    RCC_CR |= RCC_CR_PLLON;
    (void)board_wait_set(&RCC_CR, RCC_CR_PLLRDY, 100000u);
    /* AHB 168 MHz, APB1 42 MHz (max 42), APB2 84 MHz (max 84). */
    RCC_CFGR = RCC_CFGR_PPRE1_DIV4 | RCC_CFGR_PPRE2_DIV2 | RCC_CFGR_SW_PLL;
    (void)board_wait_set(&RCC_CFGR, RCC_CFGR_SWS_PLL, 100000u);
}

void board_pin_mode(uint32_t gpio_base, unsigned pin, uint32_t mode, uint32_t af)
{
    GPIO_MODER(gpio_base) = (GPIO_MODER(gpio_base) & ~(3u << (2u * pin))) | (mode << (2u * pin));
    GPIO_OSPEEDR(gpio_base) |= 2u << (2u * pin); /* fast: clean SPI edges */
    if (mode == GPIO_MODE_AF) {
        volatile uint32_t *afr = pin < 8u ? &GPIO_AFRL(gpio_base) : &GPIO_AFRH(gpio_base);
        unsigned shift = 4u * (pin % 8u);
        *afr = (*afr & ~(0xFu << shift)) | (af << shift);
    }
}

/* ---- millisecond tick ------------------------------------------------------------------ */

static volatile uint32_t ticks_ms;

void SysTick_Handler(void)
{
    ticks_ms++;
}

uint32_t hal_millis(void)
{
    return ticks_ms;
}

bool hal_wait_for_event(uint32_t wake_at_ms)
{
    (void)wake_at_ms; /* SysTick wakes the core every millisecond anyway */
    __asm volatile("wfi" ::: "memory");
    return true;
}

void hal_board_init(void)
{
    board_watchdog_read_reset_cause(); /* before anything can clear the flags */
    clock_init();
    RCC_AHB1ENR |= RCC_AHB1ENR_GPIOA | RCC_AHB1ENR_GPIOC;
    board_uart_init();
    board_spi_init();
    board_adc_init();
    SYST_RVR = CORE_CLOCK_HZ / 1000u - 1u;
    SYST_CVR = 0u;
    SYST_CSR = SYST_CSR_CLKSOURCE_CPU | SYST_CSR_TICKINT | SYST_CSR_ENABLE;
}
