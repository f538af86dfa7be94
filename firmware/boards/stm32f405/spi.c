/* SPI1 master, mode 1 (CPOL 0, CPHA 1: the MAX31856 samples SDI on the falling edge... and
 * accepts modes 1 and 3), 84 MHz / 32 = 2.6 MHz (chip maximum 5 MHz), software chip selects
 * CS0..CS7 on PC0..PC7. */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "board_internal.h"
#include "box_config.h"
#include "hal_spi.h"
#include "stm32f405_regs.h"

#define SPI_BR_DIV32 4u
#define SPI_WAIT_TRIES 10000u /* one byte takes ~3 us = ~500 core cycles */

_Static_assert(BOX_MAX_CHANNELS <= 8, "chip selects are PC0..PC7");

void board_spi_init(void)
{
    RCC_APB2ENR |= RCC_APB2ENR_SPI1;
    board_pin_mode(GPIOA_BASE, 5, GPIO_MODE_AF, 5);
    board_pin_mode(GPIOA_BASE, 6, GPIO_MODE_AF, 5);
    board_pin_mode(GPIOA_BASE, 7, GPIO_MODE_AF, 5);
    for (unsigned cs = 0; cs < BOX_MAX_CHANNELS; cs++) {
        GPIO_BSRR(GPIOC_BASE) = 1u << cs; /* deselected before the pin drives */
        board_pin_mode(GPIOC_BASE, cs, GPIO_MODE_OUTPUT, 0);
    }
    SPI1_CR1 = SPI_CR1_CPHA | SPI_CR1_MSTR | SPI_CR1_BR(SPI_BR_DIV32) | SPI_CR1_SSM |
               SPI_CR1_SSI | SPI_CR1_SPE;
}

static void short_delay(void)
{
    /* >= 400 ns chip-select high time between frames (tCWH): ~100 cycles at 168 MHz. */
    for (volatile unsigned i = 0; i < 30u; i++) {
    }
}

bool hal_spi_transfer(uint8_t cs, const uint8_t *tx, uint8_t *rx, size_t len)
{
    if (cs >= BOX_MAX_CHANNELS) {
        return false;
    }
    bool ok = true;
    GPIO_BSRR(GPIOC_BASE) = 1u << (16u + cs); /* select (low) */
    for (size_t i = 0; i < len && ok; i++) {
        ok = board_wait_set(&SPI1_SR, SPI_SR_TXE, SPI_WAIT_TRIES);
        if (ok) {
            SPI1_DR = tx ? tx[i] : 0u;
            ok = board_wait_set(&SPI1_SR, SPI_SR_RXNE, SPI_WAIT_TRIES);
        }
        if (ok) {
            uint8_t b = (uint8_t)SPI1_DR;
            if (rx) {
                rx[i] = b;
            }
        }
    }
    for (uint32_t tries = SPI_WAIT_TRIES; (SPI1_SR & SPI_SR_BSY) && tries > 0u; tries--) {
    }
    GPIO_BSRR(GPIOC_BASE) = 1u << cs; /* deselect */
    short_delay();
    return ok;
}
