/* Protocol line encoder: CRC-16/CCITT-FALSE and field formatting. The Python decoder checks the
 * same encoder end to end (tests/test_protocol_firmware.py). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "crc16.h"
#include "line.h"

static const char *finish(line_t *l)
{
    size_t n = line_finish(l);
    assert_true(n > 0u);
    assert_true(n < LINE_MAX);
    l->buf[n] = '\0';
    return l->buf;
}

static void test_Crc16_ShouldMatchTheCcittFalseCheckValue(void **state)
{
    (void)state;
    /* The catalogue check value of CRC-16/CCITT-FALSE for "123456789" is 0x29B1. */
    assert_int_equal(crc16_update(CRC16_INIT, (const uint8_t *)"123456789", 9), 0x29B1);
    assert_int_equal(crc16_update(CRC16_INIT, (const uint8_t *)"", 0), 0xFFFF);
}

static void test_Crc16_ShouldGiveTheSameResultInPieces(void **state)
{
    (void)state;
    uint16_t crc = crc16_update(CRC16_INIT, (const uint8_t *)"1234", 4);
    crc = crc16_update(crc, (const uint8_t *)"56789", 5);
    assert_int_equal(crc, 0x29B1);
}

static void test_Line_ShouldFrameThePayloadWithItsCrc(void **state)
{
    (void)state;
    line_t l;
    line_begin(&l, "E");
    line_sep(&l);
    line_put_str(&l, "BINARY");
    /* crc16("E,BINARY") computed independently: binascii.crc_hqx(b"E,BINARY", 0xFFFF). */
    assert_string_equal(finish(&l), "$E,BINARY*AED3\r\n");
}

static void test_Line_ShouldFormatSignedAndUnsignedDecimalsAtTheirLimits(void **state)
{
    (void)state;
    line_t l;
    line_begin(&l, "T");
    line_sep(&l);
    line_put_i32(&l, INT32_MIN);
    line_sep(&l);
    line_put_i32(&l, INT32_MAX);
    line_sep(&l);
    line_put_i32(&l, 0);
    line_sep(&l);
    line_put_i32(&l, -7);
    line_sep(&l);
    line_put_u32(&l, UINT32_MAX);
    finish(&l);
    assert_memory_equal(l.buf, "$T,-2147483648,2147483647,0,-7,4294967295*", 42);
}

static void test_Line_ShouldWriteFixedWidthUpperCaseHex(void **state)
{
    (void)state;
    line_t l;
    line_begin(&l, "T");
    line_sep(&l);
    line_put_hex(&l, 0x10Cu, 4);
    line_sep(&l);
    line_put_hex(&l, 0xABCDEF12u, 8);
    line_sep(&l);
    line_put_hex(&l, 0x12345u, 4); /* only the low digits */
    finish(&l);
    assert_memory_equal(l.buf, "$T,010C,ABCDEF12,2345*", 22);
}

static void test_Line_ShouldReplaceSyntaxCharactersInNames(void **state)
{
    (void)state;
    line_t l;
    line_begin(&l, "T");
    line_sep(&l);
    line_put_name(&l, "T1,2;3:4*5$6 7_ok-8.9+");
    finish(&l);
    assert_memory_equal(l.buf, "$T,T1_2_3_4_5_6_7_ok-8.9+*", 26);
}

static void test_Line_ShouldCutNamesAt32Characters(void **state)
{
    (void)state;
    line_t l;
    line_begin(&l, "T");
    line_sep(&l);
    line_put_name(&l, "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789");
    finish(&l);
    assert_memory_equal(l.buf, "$T,ABCDEFGHIJKLMNOPQRSTUVWXYZ012345*", 36);
}

static void test_Line_ShouldRefuseALineThatDoesNotFit(void **state)
{
    (void)state;
    line_t l;
    line_begin(&l, "C");
    for (int i = 0; i < 200; i++) {
        line_sep(&l);
        line_put_i32(&l, -123456);
    }
    assert_true(l.overflow);
    assert_int_equal(line_finish(&l), 0);
}

static void test_Line_ShouldFillTheBufferExactly(void **state)
{
    (void)state;
    line_t l;
    line_begin(&l, "T");
    while (l.len < LINE_MAX - LINE_TRAILER_LEN) {
        line_put_char(&l, 'x');
    }
    assert_false(l.overflow);
    assert_int_equal(line_finish(&l), LINE_MAX);
    assert_int_equal(l.buf[LINE_MAX - 1], '\n');
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_Crc16_ShouldMatchTheCcittFalseCheckValue),
        cmocka_unit_test(test_Crc16_ShouldGiveTheSameResultInPieces),
        cmocka_unit_test(test_Line_ShouldFrameThePayloadWithItsCrc),
        cmocka_unit_test(test_Line_ShouldFormatSignedAndUnsignedDecimalsAtTheirLimits),
        cmocka_unit_test(test_Line_ShouldWriteFixedWidthUpperCaseHex),
        cmocka_unit_test(test_Line_ShouldReplaceSyntaxCharactersInNames),
        cmocka_unit_test(test_Line_ShouldCutNamesAt32Characters),
        cmocka_unit_test(test_Line_ShouldRefuseALineThatDoesNotFit),
        cmocka_unit_test(test_Line_ShouldFillTheBufferExactly),
    };
    return cmocka_run_group_tests_name("line", tests, NULL, NULL);
}
