/* Command parser: well-formed commands, malformed, over-long and binary input. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "cmd.h"

#define MAX_RESULTS 16

static cmd_t results[MAX_RESULTS];
static int n_results;

/* Push a byte string through a fresh reader; collect every completed command. */
static void feed(const char *bytes, size_t len)
{
    cmd_reader_t r;
    cmd_reader_init(&r);
    n_results = 0;
    for (size_t i = 0; i < len; i++) {
        cmd_t c;
        if (cmd_reader_push(&r, (uint8_t)bytes[i], &c)) {
            assert_true(n_results < MAX_RESULTS);
            results[n_results++] = c;
        }
    }
}

#define FEED(s) feed((s), sizeof(s) - 1u)

static void assert_error(int i, const char *reason)
{
    assert_int_equal(results[i].kind, CMD_ERROR);
    assert_string_equal(results[i].reason, reason);
}

static void test_Cmd_ShouldRecogniseInfoAndStatus(void **state)
{
    (void)state;
    FEED("INFO\r\nSTATUS\n");
    assert_int_equal(n_results, 2);
    assert_int_equal(results[0].kind, CMD_INFO);
    assert_int_equal(results[1].kind, CMD_STATUS);
}

static void test_Cmd_ShouldRecogniseZeroWithoutArgumentsOnly(void **state)
{
    (void)state;
    FEED("ZERO\r\nZERO 1\nzero\nZERO \nZEROS\n");
    assert_int_equal(n_results, 5);
    assert_int_equal(results[0].kind, CMD_ZERO);
    for (int i = 1; i < 5; i++) {
        assert_error(i, "UNKNOWN");
    }
}

static void test_Cmd_ShouldAcceptCrLfAndBareCrAsLineEnds(void **state)
{
    (void)state;
    FEED("INFO\rINFO\r\n\r\nINFO\n");
    assert_int_equal(n_results, 3); /* the empty lines between are ignored */
}

static void test_Cmd_ShouldParseRateWithinOneTo3600(void **state)
{
    (void)state;
    FEED("RATE 1\nRATE 3600\nRATE 010\n");
    assert_int_equal(n_results, 3);
    assert_int_equal(results[0].kind, CMD_RATE);
    assert_int_equal(results[0].arg, 1);
    assert_int_equal(results[1].arg, 3600);
    assert_int_equal(results[2].arg, 10);
}

static void test_Cmd_ShouldRejectBadRateArguments(void **state)
{
    (void)state;
    FEED("RATE 0\nRATE 3601\nRATE\nRATE x\nRATE -5\nRATE  5\nRATE 5 \nRATE 99999999999\n");
    assert_int_equal(n_results, 8);
    for (int i = 0; i < 8; i++) {
        assert_error(i, "BAD_ARG");
    }
}

static void test_Cmd_ShouldParseResumeWithinZeroTo65535(void **state)
{
    (void)state;
    FEED("RESUME 0\nRESUME 65535\nRESUME 7\n");
    assert_int_equal(n_results, 3);
    assert_int_equal(results[0].kind, CMD_RESUME);
    assert_int_equal(results[0].arg, 0);
    assert_int_equal(results[1].arg, 65535);
    assert_int_equal(results[2].arg, 7);
    FEED("RESUME\nRESUME 65536\nRESUME -1\nRESUME x\nRESUME 5 \n");
    assert_int_equal(n_results, 5); /* each feed starts a new list */
    for (int i = 0; i < 5; i++) {
        assert_error(i, "BAD_ARG");
    }
}

static void test_Cmd_ShouldParseSnapAndLoadPieces(void **state)
{
    (void)state;
    FEED("SNAP\nLOAD 0 00ff\nLOAD 65535 A5\n"
         "LOAD 1024 000102030405060708090a0b0c0d0e0f1011121314151617\n");
    assert_int_equal(n_results, 4);
    assert_int_equal(results[0].kind, CMD_SNAP);
    assert_int_equal(results[1].kind, CMD_LOAD);
    assert_int_equal(results[1].arg, 0);
    assert_int_equal(results[1].n_bytes, 2);
    assert_int_equal(results[1].data[0], 0x00);
    assert_int_equal(results[1].data[1], 0xFF);
    assert_int_equal(results[2].arg, 65535);
    assert_int_equal(results[2].data[0], 0xA5);
    assert_int_equal(results[3].arg, 1024);
    assert_int_equal(results[3].n_bytes, CMD_LOAD_MAX_BYTES);
    for (unsigned i = 0; i < CMD_LOAD_MAX_BYTES; i++) {
        assert_int_equal(results[3].data[i], i);
    }
    /* no data, odd digits, not hex, 25 bytes, offset beyond 65535, two spaces, sign, text */
    FEED("LOAD\nLOAD 0\nLOAD 0 \nLOAD 0 abc\nLOAD 0 0g\n"
         "LOAD 0 00010203040506070809101112131415161718192021222324\n"
         "LOAD 65536 00\nLOAD 0  00\nLOAD -1 00\nLOAD x 00\nLOAD 0 00 \n");
    assert_int_equal(n_results, 11);
    for (int i = 0; i < 11; i++) {
        assert_error(i, "BAD_ARG");
    }
}

static void test_Cmd_ShouldAnswerUnknownToOtherCommandsAndWrongCase(void **state)
{
    (void)state;
    FEED("info\nINFOX\n INFO\nSTATUS 1\nRATEX 5\nHELLO\n");
    assert_int_equal(n_results, 6);
    for (int i = 0; i < 6; i++) {
        assert_error(i, "UNKNOWN");
    }
}

static void test_Cmd_ShouldAcceptALineOfExactly64Characters(void **state)
{
    (void)state;
    char line[66];
    memset(line, 'A', 64);
    line[64] = '\n';
    feed(line, 65);
    assert_int_equal(n_results, 1);
    assert_error(0, "UNKNOWN");
}

static void test_Cmd_ShouldDiscardAnOverLongLineAndAnswerOnce(void **state)
{
    (void)state;
    char line[300];
    memset(line, 'A', 290);
    memcpy(line + 290, "\nINFO\n", 6);
    feed(line, 296);
    assert_int_equal(n_results, 2);
    assert_error(0, "TOO_LONG");
    assert_int_equal(results[1].kind, CMD_INFO); /* the next line is read normally */
}

static void test_Cmd_ShouldAnswerBinaryForBytesOutsidePrintableAscii(void **state)
{
    (void)state;
    static const char bad[] = {'I', 'N', (char)0xC6, 'O', '\n', 0x00, '\n', 'A', 0x7F, '\n',
                               '\t', 'I', 'N', 'F', 'O', '\n', 'I', 'N', 'F', 'O', '\n'};
    feed(bad, sizeof bad);
    assert_int_equal(n_results, 5);
    assert_error(0, "BINARY");
    assert_error(1, "BINARY"); /* a lone NUL is a line with content too */
    assert_error(2, "BINARY");
    assert_error(3, "BINARY");
    assert_int_equal(results[4].kind, CMD_INFO);
}

static void test_Cmd_ShouldPreferBinaryWhenALineIsBothTooLongAndBinary(void **state)
{
    (void)state;
    char line[200];
    for (int i = 0; i < 199; i++) {
        line[i] = (char)(0x80 + (i % 100));
    }
    line[199] = '\n';
    feed(line, sizeof line);
    assert_int_equal(n_results, 1);
    assert_error(0, "BINARY");
}

static void test_Cmd_ShouldSurviveEveryByteValueWithoutAnswerFlood(void **state)
{
    (void)state;
    /* All 256 byte values in order: CR (13) and LF (10) split it into lines; at most one
     * answer per line end. */
    char all[256];
    for (int i = 0; i < 256; i++) {
        all[i] = (char)i;
    }
    feed(all, sizeof all);
    assert_true(n_results <= 2);
    for (int i = 0; i < n_results; i++) {
        assert_error(i, "BINARY");
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_Cmd_ShouldRecogniseInfoAndStatus),
        cmocka_unit_test(test_Cmd_ShouldRecogniseZeroWithoutArgumentsOnly),
        cmocka_unit_test(test_Cmd_ShouldAcceptCrLfAndBareCrAsLineEnds),
        cmocka_unit_test(test_Cmd_ShouldParseRateWithinOneTo3600),
        cmocka_unit_test(test_Cmd_ShouldRejectBadRateArguments),
        cmocka_unit_test(test_Cmd_ShouldParseResumeWithinZeroTo65535),
        cmocka_unit_test(test_Cmd_ShouldAnswerUnknownToOtherCommandsAndWrongCase),
        cmocka_unit_test(test_Cmd_ShouldParseSnapAndLoadPieces),
        cmocka_unit_test(test_Cmd_ShouldAcceptALineOfExactly64Characters),
        cmocka_unit_test(test_Cmd_ShouldDiscardAnOverLongLineAndAnswerOnce),
        cmocka_unit_test(test_Cmd_ShouldAnswerBinaryForBytesOutsidePrintableAscii),
        cmocka_unit_test(test_Cmd_ShouldPreferBinaryWhenALineIsBothTooLongAndBinary),
        cmocka_unit_test(test_Cmd_ShouldSurviveEveryByteValueWithoutAnswerFlood),
    };
    return cmocka_run_group_tests_name("cmd", tests, NULL, NULL);
}
