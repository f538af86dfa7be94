#include "max31856.h"

#include "box_config.h"
#include "hal_spi.h"

uint8_t max31856_cr0(void)
{
    return (uint8_t)(MAX31856_CR0_CMODE | MAX31856_CR0_OCFAULT_01 |
                     (BOX_MAINS_50HZ ? MAX31856_CR0_50HZ : 0u));
}

uint8_t max31856_cr1(uint8_t tc_type)
{
    uint8_t type;
    switch (tc_type) {
    case MAX31856_TC_K:
        type = MAX31856_CR1_TYPE_K;
        break;
    case MAX31856_TC_J:
        type = MAX31856_CR1_TYPE_J;
        break;
    default:
        return 0xFFu;
    }
    return (uint8_t)(((unsigned)BOX_TC_AVGSEL << MAX31856_CR1_AVGSEL_SHIFT) | type);
}

uint8_t max31856_mask(void)
{
    /* Every fault drives the FAULT pin (a LED on the box); the firmware polls SR anyway. */
    return 0x00u;
}

int32_t max31856_decode_ltcb(uint8_t h, uint8_t m, uint8_t l)
{
    uint32_t raw = ((uint32_t)h << 11) | ((uint32_t)m << 3) | ((uint32_t)l >> 5); /* 19 bits */
    /* Sign-extend bit 18 without shifting a negative value. */
    return (raw & 0x40000u) ? (int32_t)raw - (int32_t)0x80000 : (int32_t)raw;
}

static bool config_matches(const uint8_t *rx, uint8_t tc_type)
{
    return rx[0] == max31856_cr0() && rx[1] == max31856_cr1(tc_type) && rx[2] == max31856_mask();
}

static bool read_config(uint8_t cs, uint8_t cfg[3])
{
    uint8_t tx[4] = {MAX31856_REG_CR0, 0, 0, 0};
    uint8_t rx[4];
    if (!hal_spi_transfer(cs, tx, rx, sizeof tx)) {
        return false;
    }
    cfg[0] = rx[1];
    cfg[1] = rx[2];
    cfg[2] = rx[3];
    return true;
}

bool max31856_configure(uint8_t cs, uint8_t tc_type)
{
    uint8_t cr1 = max31856_cr1(tc_type);
    if (cr1 == 0xFFu) {
        return false;
    }
    uint8_t tx[4] = {MAX31856_WRITE | MAX31856_REG_CR0, max31856_cr0(), cr1, max31856_mask()};
    if (!hal_spi_transfer(cs, tx, 0, sizeof tx)) {
        return false;
    }
    uint8_t cfg[3];
    return read_config(cs, cfg) && config_matches(cfg, tc_type);
}

bool max31856_read(uint8_t cs, uint8_t tc_type, max31856_reading_t *out)
{
    out->code = 0;
    out->sr = 0;
    out->responding = false;

    uint8_t cfg[3];
    if (!read_config(cs, cfg)) {
        return false;
    }
    if (!config_matches(cfg, tc_type)) {
        /* Lost configuration (power glitch) or no chip: rewrite it; this sample is not trusted
         * because the chip may not have converted with the right settings yet. */
        (void)max31856_configure(cs, tc_type);
        return false;
    }
    uint8_t tx[5] = {MAX31856_REG_LTCBH, 0, 0, 0, 0};
    uint8_t rx[5];
    if (!hal_spi_transfer(cs, tx, rx, sizeof tx)) {
        return false;
    }
    out->code = max31856_decode_ltcb(rx[1], rx[2], rx[3]);
    out->sr = rx[4];
    out->responding = true;
    return true;
}
