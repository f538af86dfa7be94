/* MAX31856 driver against the register-level chip model (emul/max31856_sim.c).
 * Expected register values and codes are worked out from the datasheet in the comments, not
 * taken from the driver's own helpers. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "hal_spi.h"
#include "max31856.h"
#include "max31856_sim.h"

#define N_CHIPS 3

static max31856_sim_t chips[N_CHIPS];
static bool bus_fails;
static unsigned transfers;

bool hal_spi_transfer(uint8_t cs, const uint8_t *tx, uint8_t *rx, size_t len)
{
    transfers++;
    if (bus_fails || cs >= N_CHIPS) {
        return false;
    }
    max31856_sim_transfer(&chips[cs], tx, rx, len);
    return true;
}

static int setup(void **state)
{
    (void)state;
    for (int i = 0; i < N_CHIPS; i++) {
        max31856_sim_reset(&chips[i]);
    }
    bus_fails = false;
    transfers = 0;
    return 0;
}

/* Datasheet: CR0 = CMODE (0x80) | OCFAULT=01 (0x10) | 50 Hz (0x01) = 0x91;
 * CR1 = AVGSEL=010 (4 samples, 0x20) | TC type K (0011) = 0x23, J (0010) = 0x22;
 * MASK = 0x00 (every fault asserts the FAULT pin). */
static void test_Max31856_ShouldWriteAutoConversionOpenDetectAndTypeK(void **state)
{
    (void)state;
    assert_true(max31856_configure(1, MAX31856_TC_K));
    assert_int_equal(chips[1].regs[0x00], 0x91);
    assert_int_equal(chips[1].regs[0x01], 0x23);
    assert_int_equal(chips[1].regs[0x02], 0x00);
    assert_int_equal(chips[1].config_writes, 3);
    /* The other chips were not touched. */
    assert_int_equal(chips[0].config_writes, 0);
    assert_int_equal(chips[2].config_writes, 0);
}

static void test_Max31856_ShouldSelectTypeJPerChannel(void **state)
{
    (void)state;
    assert_true(max31856_configure(0, MAX31856_TC_J));
    assert_true(max31856_configure(2, MAX31856_TC_K));
    assert_int_equal(chips[0].regs[0x01], 0x22);
    assert_int_equal(chips[2].regs[0x01], 0x23);
}

static void test_Max31856_ShouldRefuseUnknownThermocoupleType(void **state)
{
    (void)state;
    assert_false(max31856_configure(0, 7));
    assert_int_equal(chips[0].config_writes, 0);
}

static void test_Max31856_ShouldReportAbsentChipAsNotResponding(void **state)
{
    (void)state;
    chips[1].present = false; /* MISO pulled up: every byte reads 0xFF */
    assert_false(max31856_configure(1, MAX31856_TC_K));
    max31856_reading_t r;
    assert_false(max31856_read(1, MAX31856_TC_K, &r));
    assert_false(r.responding);
}

static void test_Max31856_ShouldReportBusFailureAsNotResponding(void **state)
{
    (void)state;
    assert_true(max31856_configure(0, MAX31856_TC_K));
    bus_fails = true;
    max31856_reading_t r;
    assert_false(max31856_read(0, MAX31856_TC_K, &r));
    assert_false(r.responding);
}

static void load_ltcb(max31856_sim_t *chip, uint8_t h, uint8_t m, uint8_t l)
{
    chip->regs[0x0C] = h;
    chip->regs[0x0D] = m;
    chip->regs[0x0E] = l;
}

static int32_t read_code(max31856_sim_t *chip, uint8_t cs)
{
    max31856_reading_t r;
    assert_true(max31856_read(cs, MAX31856_TC_K, &r));
    assert_true(r.responding);
    (void)chip;
    return r.code;
}

/* +25.0 degC = 3200/128: 3200 << 5 = 0x019000 -> LTCBH 0x01, LTCBM 0x90, LTCBL 0x00. */
static void test_Max31856_ShouldDecodePositiveTemperature(void **state)
{
    (void)state;
    assert_true(max31856_configure(0, MAX31856_TC_K));
    load_ltcb(&chips[0], 0x01, 0x90, 0x00);
    assert_int_equal(read_code(&chips[0], 0), 3200);
}

/* Datasheet example: -250 degC = 1111 0000 0110 0000 0000 0 -> 0xF0 0x60 0x00 = -32000/128;
 * -1/128 degC is all ones in 19 bits -> 0xFF 0xFF 0xE0. */
static void test_Max31856_ShouldSignExtendNegativeTemperature(void **state)
{
    (void)state;
    assert_true(max31856_configure(0, MAX31856_TC_K));
    load_ltcb(&chips[0], 0xF0, 0x60, 0x00);
    assert_int_equal(read_code(&chips[0], 0), -32000);
    load_ltcb(&chips[0], 0xFF, 0xFF, 0xE0);
    assert_int_equal(read_code(&chips[0], 0), -1);
}

static void test_Max31856_ShouldDecodeBothEndsOfThe19BitRange(void **state)
{
    (void)state;
    assert_int_equal(max31856_decode_ltcb(0x7F, 0xFF, 0xE0), 262143);  /* 2^18 - 1 */
    assert_int_equal(max31856_decode_ltcb(0x80, 0x00, 0x00), -262144); /* -2^18 */
    assert_int_equal(max31856_decode_ltcb(0x00, 0x00, 0x20), 1);
    assert_int_equal(max31856_decode_ltcb(0x00, 0x00, 0x00), 0);
}

static void test_Max31856_ShouldIgnoreTheFiveUnusedLowBits(void **state)
{
    (void)state;
    assert_int_equal(max31856_decode_ltcb(0x01, 0x90, 0x1F), 3200);
    assert_int_equal(max31856_decode_ltcb(0xFF, 0xFF, 0xFF), -1);
}

static void test_Max31856_ShouldReadWhatTheChipConverted(void **state)
{
    (void)state;
    assert_true(max31856_configure(2, MAX31856_TC_K));
    max31856_sim_set_temperature(&chips[2], -5121);
    assert_int_equal(read_code(&chips[2], 2), -5121);
    max31856_sim_set_temperature(&chips[2], 25599);
    assert_int_equal(read_code(&chips[2], 2), 25599);
}

static void test_Max31856_ShouldReportEveryFaultStatusBit(void **state)
{
    (void)state;
    assert_true(max31856_configure(0, MAX31856_TC_K));
    /* SR bits 0..7: OPEN, OVUV, TCLOW, TCHIGH, CJLOW, CJHIGH, TCRANGE, CJRANGE. */
    static const uint8_t bits[] = {0x01, 0x02, 0x04, 0x08, 0x10, 0x20, 0x40, 0x80};
    static const uint8_t named[] = {MAX31856_SR_OPEN,   MAX31856_SR_OVUV,   MAX31856_SR_TCLOW,
                                    MAX31856_SR_TCHIGH, MAX31856_SR_CJLOW,  MAX31856_SR_CJHIGH,
                                    MAX31856_SR_TCRANGE, MAX31856_SR_CJRANGE};
    for (unsigned i = 0; i < sizeof bits; i++) {
        assert_int_equal(named[i], bits[i]);
        max31856_sim_set_fault(&chips[0], bits[i]);
        max31856_reading_t r;
        assert_true(max31856_read(0, MAX31856_TC_K, &r));
        assert_int_equal(r.sr, bits[i]);
    }
    max31856_sim_set_fault(&chips[0], 0x00);
    max31856_reading_t r;
    assert_true(max31856_read(0, MAX31856_TC_K, &r));
    assert_int_equal(r.sr, 0);
}

static void test_Max31856_ShouldSeeOpenThermocoupleOnlyBecauseDetectionIsEnabled(void **state)
{
    (void)state;
    /* An unconfigured chip (power-on CR0 = 0x00) does not detect open circuits at all. */
    max31856_sim_set_fault(&chips[1], MAX31856_SR_OPEN);
    assert_int_equal(chips[1].regs[0x0F], 0x00);
    assert_true(max31856_configure(1, MAX31856_TC_K));
    max31856_reading_t r;
    assert_true(max31856_read(1, MAX31856_TC_K, &r));
    assert_int_equal(r.sr, MAX31856_SR_OPEN);
}

static void test_Max31856_ShouldRewriteConfigurationLostInABrownOut(void **state)
{
    (void)state;
    assert_true(max31856_configure(0, MAX31856_TC_J));
    max31856_sim_reset(&chips[0]); /* power glitch: registers back to their defaults */
    max31856_reading_t r;
    assert_false(max31856_read(0, MAX31856_TC_J, &r)); /* this sample is not trusted */
    assert_int_equal(chips[0].regs[0x00], 0x91);
    assert_int_equal(chips[0].regs[0x01], 0x22);
    max31856_sim_set_temperature(&chips[0], 1234);
    assert_true(max31856_read(0, MAX31856_TC_J, &r));
    assert_int_equal(r.code, 1234);
}

static void test_Max31856_ShouldReadAChannelInTwoBursts(void **state)
{
    (void)state;
    assert_true(max31856_configure(0, MAX31856_TC_K));
    transfers = 0;
    max31856_reading_t r;
    assert_true(max31856_read(0, MAX31856_TC_K, &r));
    assert_int_equal(transfers, 2); /* CR0..MASK, then LTCBH..SR */
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_Max31856_ShouldWriteAutoConversionOpenDetectAndTypeK, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldSelectTypeJPerChannel, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldRefuseUnknownThermocoupleType, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldReportAbsentChipAsNotResponding, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldReportBusFailureAsNotResponding, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldDecodePositiveTemperature, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldSignExtendNegativeTemperature, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldDecodeBothEndsOfThe19BitRange, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldIgnoreTheFiveUnusedLowBits, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldReadWhatTheChipConverted, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldReportEveryFaultStatusBit, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldSeeOpenThermocoupleOnlyBecauseDetectionIsEnabled,
                               setup),
        cmocka_unit_test_setup(test_Max31856_ShouldRewriteConfigurationLostInABrownOut, setup),
        cmocka_unit_test_setup(test_Max31856_ShouldReadAChannelInTwoBursts, setup),
    };
    return cmocka_run_group_tests_name("max31856", tests, NULL, NULL);
}
