/* Register-level model of one MAX31856 as seen from its SPI pins (docs/native-board.md).
 *
 * Written from the datasheet, independently of the driver: 16 registers with their power-on
 * defaults, write address = reg | 0x80, auto-increment within a chip-select frame, read-only
 * LTCB/SR. Conversions only update LTCB while CR0 selects automatic conversion, and the OPEN
 * fault only shows in SR while CR0 enables open-circuit detection, so a driver that forgets its
 * configuration gets stale or fault-blind data here just as on the real chip. */
#ifndef MAX31856_SIM_H
#define MAX31856_SIM_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define MAX31856_SIM_NREGS 16u
#define MAX31856_SIM_CODE_MIN (-262144) /* 19-bit two's complement */
#define MAX31856_SIM_CODE_MAX 262143

typedef struct {
    uint8_t regs[MAX31856_SIM_NREGS];
    bool present;          /* false: MISO floats high, every byte reads 0xFF */
    uint8_t fault;         /* fault conditions present at the inputs (SR bit layout) */
    uint32_t config_writes; /* bytes written to CR0..MASK, for tests */
} max31856_sim_t;

/* Power-on state. */
void max31856_sim_reset(max31856_sim_t *chip);

/* One chip-select frame: tx[0] is the address byte. */
void max31856_sim_transfer(max31856_sim_t *chip, const uint8_t *tx, uint8_t *rx, size_t len);

/* The thermocouple now reads `code` (1/128 degC, clipped to 19 bits): latched into LTCB by the
 * next automatic conversion, i.e. at once if CR0 has CMODE set. */
void max31856_sim_set_temperature(max31856_sim_t *chip, int32_t code);

/* Fault conditions at the inputs (SR layout): visible in SR according to CR0. */
void max31856_sim_set_fault(max31856_sim_t *chip, uint8_t fault);

#endif
