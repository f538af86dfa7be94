/* SPI HAL of the native board: chip select n talks to simulated MAX31856 number n. */
#include "box_config.h"
#include "hal_spi.h"
#include "native_board.h"

static max31856_sim_t chips[BOX_MAX_CHANNELS];
static bool chips_ready;
static volatile bool hang_pending;

void native_spi_hang_once(void)
{
    hang_pending = true;
}

static void ensure_chips(void)
{
    if (!chips_ready) {
        for (unsigned i = 0; i < BOX_MAX_CHANNELS; i++) {
            max31856_sim_reset(&chips[i]);
        }
        chips_ready = true;
    }
}

max31856_sim_t *native_chip(uint8_t cs)
{
    ensure_chips();
    return cs < BOX_MAX_CHANNELS ? &chips[cs] : 0;
}

void native_set_chip_count(uint8_t count)
{
    ensure_chips();
    for (unsigned i = 0; i < BOX_MAX_CHANNELS; i++) {
        chips[i].present = i < count;
    }
}

bool hal_spi_transfer(uint8_t cs, const uint8_t *tx, uint8_t *rx, size_t len)
{
    if (hang_pending) {
        hang_pending = false;
        for (volatile uint32_t spin = 0;; spin++) {
            /* like polling a status flag that never sets; only the watchdog gets us out */
        }
    }
    max31856_sim_t *chip = native_chip(cs);
    if (chip == 0) {
        return false; /* no such chip-select line on the board */
    }
    max31856_sim_transfer(chip, tx, rx, len);
    return true;
}
