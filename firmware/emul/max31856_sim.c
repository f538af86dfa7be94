#include "max31856_sim.h"

/* Datasheet register map (the driver has its own copy on purpose: this model must not share
 * the driver's mistakes). */
enum {
    CR0 = 0x00, CR1 = 0x01, MASK = 0x02, CJHF = 0x03, CJLF = 0x04, LTHFTH = 0x05, LTHFTL = 0x06,
    LTLFTH = 0x07, LTLFTL = 0x08, CJTO = 0x09, CJTH = 0x0A, CJTL = 0x0B, LTCBH = 0x0C,
    LTCBM = 0x0D, LTCBL = 0x0E, SR = 0x0F
};

#define CR0_CMODE 0x80u
#define CR0_OCFAULT 0x30u
#define SR_OPEN 0x01u

static void update_sr(max31856_sim_t *chip)
{
    uint8_t sr = chip->fault;
    if ((chip->regs[CR0] & CR0_OCFAULT) == 0u) {
        sr &= (uint8_t)~SR_OPEN; /* open-circuit detection disabled */
    }
    chip->regs[SR] = sr;
}

void max31856_sim_reset(max31856_sim_t *chip)
{
    static const uint8_t defaults[MAX31856_SIM_NREGS] = {
        [CR0] = 0x00, [CR1] = 0x03, [MASK] = 0xFF, [CJHF] = 0x7F, [CJLF] = 0xC0,
        [LTHFTH] = 0x7F, [LTHFTL] = 0xFF, [LTLFTH] = 0x80, [LTLFTL] = 0x00, [CJTO] = 0x00,
        [CJTH] = 0x00, [CJTL] = 0x00, [LTCBH] = 0x00, [LTCBM] = 0x00, [LTCBL] = 0x00, [SR] = 0x00,
    };
    for (unsigned i = 0; i < MAX31856_SIM_NREGS; i++) {
        chip->regs[i] = defaults[i];
    }
    chip->present = true;
    chip->fault = 0;
    chip->config_writes = 0;
}

void max31856_sim_transfer(max31856_sim_t *chip, const uint8_t *tx, uint8_t *rx, size_t len)
{
    if (len == 0u) {
        return;
    }
    if (!chip->present) {
        for (size_t i = 0; i < len; i++) {
            if (rx) {
                rx[i] = 0xFF;
            }
        }
        return;
    }
    bool write = (tx[0] & 0x80u) != 0u;
    unsigned addr = tx[0] & 0x0Fu;
    if (rx) {
        rx[0] = 0xFF; /* SDO is high-impedance while the address is clocked in */
    }
    for (size_t i = 1; i < len; i++) {
        if (write) {
            if (addr < LTCBH) { /* LTCB and SR are read-only */
                chip->regs[addr] = tx[i];
                if (addr <= MASK) {
                    chip->config_writes++;
                }
            }
            if (rx) {
                rx[i] = 0xFF;
            }
        } else if (rx) {
            rx[i] = chip->regs[addr];
        }
        addr = (addr + 1u) & 0x0Fu;
    }
    if (write) {
        update_sr(chip);
    }
}

void max31856_sim_set_temperature(max31856_sim_t *chip, int32_t code)
{
    if ((chip->regs[CR0] & CR0_CMODE) == 0u) {
        return; /* normally-off mode: no conversion, LTCB keeps its last value */
    }
    if (code < MAX31856_SIM_CODE_MIN) {
        code = MAX31856_SIM_CODE_MIN;
    }
    if (code > MAX31856_SIM_CODE_MAX) {
        code = MAX31856_SIM_CODE_MAX;
    }
    uint32_t raw = ((uint32_t)code & 0x7FFFFu) << 5; /* left-justified in 24 bits */
    chip->regs[LTCBH] = (uint8_t)(raw >> 16);
    chip->regs[LTCBM] = (uint8_t)(raw >> 8);
    chip->regs[LTCBL] = (uint8_t)raw;
    update_sr(chip);
}

void max31856_sim_set_fault(max31856_sim_t *chip, uint8_t fault)
{
    chip->fault = fault;
    update_sr(chip);
}
