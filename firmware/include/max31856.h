/* MAX31856 thermocouple-to-digital converter, one chip per channel on a shared SPI bus.
 *
 * The chip runs in automatic conversion mode with open-circuit detection and its fault status
 * register in comparator mode (faults clear themselves when the condition goes away), so
 * reading a channel is two short register bursts and never waits for a conversion.
 * Register facts (Maxim MAX31856 datasheet): read address = reg, write address = reg | 0x80,
 * addresses auto-increment within a burst; LTCB is 19 bits two's complement, left-justified in
 * LTCBH:LTCBM:LTCBL, LSB 2^-7 degC. */
#ifndef MAX31856_H
#define MAX31856_H

#include <stdbool.h>
#include <stdint.h>

#define MAX31856_REG_CR0 0x00u
#define MAX31856_REG_CR1 0x01u
#define MAX31856_REG_MASK 0x02u
#define MAX31856_REG_LTCBH 0x0Cu
#define MAX31856_REG_LTCBM 0x0Du
#define MAX31856_REG_LTCBL 0x0Eu
#define MAX31856_REG_SR 0x0Fu
#define MAX31856_WRITE 0x80u

/* CR0 */
#define MAX31856_CR0_CMODE 0x80u     /* automatic conversion every ~100 ms */
#define MAX31856_CR0_1SHOT 0x40u
#define MAX31856_CR0_OCFAULT_01 0x10u /* open-circuit detection, source resistance < 5 kOhm */
#define MAX31856_CR0_OCFAULT_MASK 0x30u
#define MAX31856_CR0_CJ_DISABLE 0x08u
#define MAX31856_CR0_FAULT_INT 0x04u /* 0 = comparator mode */
#define MAX31856_CR0_FAULTCLR 0x02u
#define MAX31856_CR0_50HZ 0x01u

/* CR1: AVGSEL in bits 6:4, thermocouple type in bits 3:0 */
#define MAX31856_CR1_AVGSEL_SHIFT 4u
#define MAX31856_CR1_TYPE_J 0x02u
#define MAX31856_CR1_TYPE_K 0x03u

/* Fault status register (SR) bits; the MASK register uses bits 5:0 with the same meaning
 * (1 = fault does not assert the FAULT pin). */
#define MAX31856_SR_CJRANGE 0x80u
#define MAX31856_SR_TCRANGE 0x40u
#define MAX31856_SR_CJHIGH 0x20u
#define MAX31856_SR_CJLOW 0x10u
#define MAX31856_SR_TCHIGH 0x08u
#define MAX31856_SR_TCLOW 0x04u
#define MAX31856_SR_OVUV 0x02u
#define MAX31856_SR_OPEN 0x01u

/* Thermocouple types as the model header numbers them (docs/fixed-point.md). */
#define MAX31856_TC_K 0u
#define MAX31856_TC_J 1u

typedef struct {
    int32_t code;   /* linearised temperature, 1/128 degC, sign-extended 19-bit */
    uint8_t sr;     /* fault status register */
    bool responding; /* bus completed and CR0/CR1/MASK read back as configured */
} max31856_reading_t;

/* The CR0/CR1/MASK values the driver writes for a thermocouple type (0xFF for an unknown type,
 * which no real configuration uses). */
uint8_t max31856_cr0(void);
uint8_t max31856_cr1(uint8_t tc_type);
uint8_t max31856_mask(void);

/* Write CR0, CR1 and MASK of chip `cs` and read them back; true if they read back as written. */
bool max31856_configure(uint8_t cs, uint8_t tc_type);

/* Read one channel: check the configuration (and rewrite it if the chip lost it, e.g. after a
 * brown-out — that sample is then reported as not responding), then LTCB and SR in one burst.
 * Returns out->responding. */
bool max31856_read(uint8_t cs, uint8_t tc_type, max31856_reading_t *out);

/* 19-bit two's complement LTCB (left-justified in three bytes) -> 1/128 degC. */
int32_t max31856_decode_ltcb(uint8_t h, uint8_t m, uint8_t l);

#endif
