/* The application on a fake board: the whole sample path (MAX31856 models -> driver -> model
 * runtime -> hold/slew/clamp -> protocol line) against host-generated expectations, bit for
 * bit, plus scheduling, watchdog, commands. Expectations: build/test/model/vectors.h, written
 * by test/gen_test_model.py from codegen.fixed and the documented rules. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "app.h"
#include "box_config.h"
#include "crc16.h"
#include "fake_board.h"
#include "vectors.h"

_Static_assert(BOX_MAX_CORRECTION_NM == VEC_CLAMP_NM, "build and vectors disagree on the clamp");
_Static_assert(BOX_SLEW_NM_PER_S == VEC_SLEW_NM_PER_S, "build and vectors disagree on the slew");
_Static_assert(BOX_COLD_START_SLEW == VEC_COLD_START_SLEW, "build and vectors disagree");
_Static_assert(BOX_IMPLAUSIBLE_FAULT_SAMPLES == VEC_IMPLAUSIBLE_AFTER, "build and vectors disagree");
_Static_assert(BOX_ZERO_SAMPLES == VEC_ZERO_SAMPLES, "build and vectors disagree");

typedef struct {
    long seq;
    unsigned status;
    int n_axes;
    long corr[8];
    int n_ch;
    long codes[8];
} sample_line_t;

/* Split the first line of `text` off; checks framing and CRC; returns the payload (between
 * '$' and '*') in `payload`. */
static const char *next_line(const char *text, char *payload, size_t cap)
{
    const char *end = strstr(text, "\r\n");
    assert_non_null(end);
    assert_int_equal(text[0], '$');
    const char *star = memchr(text, '*', (size_t)(end - text));
    assert_non_null(star);
    assert_int_equal(end - star, 5);
    size_t n = (size_t)(star - text - 1);
    assert_true(n < cap);
    memcpy(payload, text + 1, n);
    payload[n] = '\0';
    unsigned crc = (unsigned)strtoul(star + 1, NULL, 16);
    assert_int_equal(crc, crc16_update(CRC16_INIT, (const uint8_t *)payload, n));
    return end + 2;
}

static void parse_sample(const char *payload, sample_line_t *s)
{
    char *p;
    assert_memory_equal(payload, "C,", 2);
    s->seq = strtol(payload + 2, &p, 10);
    assert_int_equal(*p++, ',');
    s->status = (unsigned)strtoul(p, &p, 16);
    assert_int_equal(*p++, ',');
    s->n_axes = (int)strtol(p, &p, 10);
    assert_true(s->n_axes <= 8);
    for (int a = 0; a < s->n_axes; a++) {
        assert_int_equal(*p++, ',');
        s->corr[a] = strtol(p, &p, 10);
    }
    assert_int_equal(*p++, ',');
    s->n_ch = (int)strtol(p, &p, 10);
    assert_true(s->n_ch <= 8);
    for (int c = 0; c < s->n_ch; c++) {
        assert_int_equal(*p++, ',');
        s->codes[c] = strtol(p, &p, 10);
    }
    assert_int_equal(*p, '\0');
}

static void load_vector(int i)
{
    for (int c = 0; c < VEC_N_CHANNELS; c++) {
        fake_chips[c].present = vec_present[i][c];
        max31856_sim_set_temperature(&fake_chips[c], vec_codes[i][c]);
        max31856_sim_set_fault(&fake_chips[c], vec_sr[i][c]);
    }
    fake_aux = vec_aux[i];
    fake_aux_ok = vec_aux_ok[i];
}

static int boot(void **state)
{
    (void)state;
    fake_board_reset();
    fake_now_ms = 5000; /* not zero: the schedule must be relative to boot */
    app_init();
    (void)fake_uart_take();
    return 0;
}

static void advance_and_poll(uint32_t ms)
{
    fake_now_ms += ms;
    app_poll();
}

/* Feed every host vector and compare each line; before sample `warm_reset_at` (-1: never) the
 * chip resets by its watchdog and boots again: it must resume where it was, bit for bit,
 * with WDT_RESET from then on. */
static void replay_vectors(int warm_reset_at)
{
    char payload[300];
    int zeros = 0;
    unsigned sticky = 0;
    for (int i = 0; i < VEC_N; i++) {
        if (i == warm_reset_at) {
            fake_reset_by_watchdog = true;
            fake_now_ms = 0; /* the tick restarts; the backup SRAM does not */
            app_init();
            (void)fake_uart_take();
            sticky = 0x0100u; /* WDT_RESET */
        }
        if (vec_zero_before[i]) {
            fake_uart_send("ZERO\r\n");
            app_poll();
            char want[32];
            snprintf(want, sizeof want, "OK,ZERO,%d", i > 0 ? i - 1 : 0);
            assert_string_equal(next_line(fake_uart_take(), payload, sizeof payload), "");
            assert_string_equal(payload, want);
            zeros++;
        }
        load_vector(i);
        advance_and_poll(VEC_PERIOD_MS);
        const char *out = fake_uart_take();
        const char *rest = next_line(out, payload, sizeof payload);
        assert_string_equal(rest, ""); /* exactly one line per period */
        sample_line_t s;
        parse_sample(payload, &s);
        if (s.status != (vec_status[i] | sticky)) {
            fail_msg("sample %d: status %04X, expected %04X", i, s.status,
                     vec_status[i] | sticky);
        }
        assert_int_equal(s.seq, i);
        assert_int_equal(s.n_axes, VEC_N_AXES);
        for (int a = 0; a < VEC_N_AXES; a++) {
            if (s.corr[a] != vec_out_nm[i][a]) {
                fail_msg("sample %d axis %d: %ld nm, expected %d nm", i, a, s.corr[a],
                         vec_out_nm[i][a]);
            }
        }
        assert_int_equal(s.n_ch, VEC_N_CHANNELS);
        for (int c = 0; c < VEC_N_CHANNELS; c++) {
            assert_int_equal(s.codes[c], vec_shown[i][c]);
        }
    }
    assert_true(zeros >= 2);
}

static void test_App_ShouldMatchHostVectorsBitForBit(void **state)
{
    (void)state;
    replay_vectors(-1);
}

static void test_App_ShouldResumeBitForBitAfterAWatchdogReset(void **state)
{
    (void)state;
    replay_vectors(201); /* mid-run: a ZERO reference in force, filters warm, a glitch ahead */
}

static void test_App_ShouldBootColdWhenTheRetainedMemoryIsLost(void **state)
{
    (void)state;
    char payload[300];
    for (int i = 0; i < 50; i++) {
        load_vector(i);
        advance_and_poll(VEC_PERIOD_MS);
        (void)fake_uart_take();
    }
    fake_retain_clear(); /* a power cut without a backup battery */
    fake_reset_by_watchdog = true;
    app_init();
    (void)fake_uart_take();
    load_vector(50);
    advance_and_poll(VEC_PERIOD_MS);
    next_line(fake_uart_take(), payload, sizeof payload);
    sample_line_t s;
    parse_sample(payload, &s);
    assert_int_equal(s.seq, 0); /* nothing resumed: a new power-up */
    assert_true(s.status & 0x0004u); /* SLEW: walking from 0 again, as after any power-up */
}

static void test_App_ShouldRefuseResumeWhenThereIsNothingToContinue(void **state)
{
    (void)state;
    /* the vectors' model has no start reference: a cold power-up keeps nothing to continue
     * (the retained block is intact: a battery kept it) */
    for (int i = 0; i < 20; i++) {
        load_vector(i);
        advance_and_poll(VEC_PERIOD_MS);
        (void)fake_uart_take();
    }
    fake_reset_by_watchdog = false;
    app_init();
    (void)fake_uart_take();
    fake_uart_send("RESUME 3\r\n");
    advance_and_poll(1);
    assert_memory_equal(fake_uart_take(), "$E,NO_STATE*", 12);
}

static int hex_nibble(char c)
{
    return c <= '9' ? c - '0' : c - 'A' + 10;
}

static void test_App_ShouldSendTheBlockItKeepsOnSnap(void **state)
{
    (void)state;
    char payload[700];
    fake_uart_send("SNAP\r\n");
    advance_and_poll(1);
    assert_memory_equal(fake_uart_take(), "$E,NO_STATE*", 12); /* nothing sampled yet */
    for (int i = 0; i < 30; i++) {
        load_vector(i);
        advance_and_poll(VEC_PERIOD_MS);
        (void)fake_uart_take();
    }
    fake_uart_send("SNAP\r\n");
    advance_and_poll(1);
    /* The pieces, put together, are the block the box wrote to its retained memory after the
     * latest sample, byte for byte (SNAP sends what a battery would have kept). */
    static uint8_t block[4096];
    unsigned got = 0, size = 0;
    const char *out = fake_uart_take();
    for (;;) {
        out = next_line(out, payload, sizeof payload);
        if (payload[0] != 'B') {
            break;
        }
        char *p;
        unsigned off = (unsigned)strtoul(payload + 2, &p, 10);
        size = (unsigned)strtoul(p + 1, &p, 10);
        assert_int_equal(off, got);
        assert_int_equal(*p++, ',');
        for (; p[0] != '\0'; p += 2) {
            block[got++] = (uint8_t)(hex_nibble(p[0]) * 16 + hex_nibble(p[1]));
        }
    }
    assert_string_equal(payload, "OK,SNAP,29");
    assert_true(size > 1000u && size < sizeof block);
    assert_int_equal(got, size);
    assert_memory_equal(block, fake_retained, size);
}

static void test_App_ShouldRefuseLoadWhileItsOwnStateIsInUse(void **state)
{
    (void)state;
    /* the vectors' model has no start reference: the box's own state is always in use */
    fake_uart_send("LOAD 0 00\r\n");
    advance_and_poll(1);
    assert_memory_equal(fake_uart_take(), "$E,IN_USE*", 10);
}

static void test_App_ShouldConfigureEveryChipForItsThermocoupleType(void **state)
{
    (void)state;
    /* vectors: channels 2 and 5 are type J (CR1 0x22), the others K (0x23); CR0 0x91. */
    for (int c = 0; c < VEC_N_CHANNELS; c++) {
        assert_int_equal(fake_chips[c].regs[0x00], 0x91);
        assert_int_equal(fake_chips[c].regs[0x01], (c == 2 || c == 5) ? 0x22 : 0x23);
    }
}

static void test_App_ShouldNotSampleBeforeThePeriodHasPassed(void **state)
{
    (void)state;
    load_vector(0);
    advance_and_poll(VEC_PERIOD_MS - 1u);
    assert_string_equal(fake_uart_take(), "");
    advance_and_poll(1);
    assert_memory_equal(fake_uart_take(), "$C,0,", 5);
    advance_and_poll(VEC_PERIOD_MS / 2u);
    assert_string_equal(fake_uart_take(), "");
    advance_and_poll(VEC_PERIOD_MS / 2u);
    assert_memory_equal(fake_uart_take(), "$C,1,", 5);
}

static void test_App_ShouldShowMissedPeriodsAsAGapInSeq(void **state)
{
    (void)state;
    load_vector(0);
    advance_and_poll(VEC_PERIOD_MS);
    (void)fake_uart_take();
    advance_and_poll(VEC_PERIOD_MS * 3u + VEC_PERIOD_MS / 2u); /* a stalled loop */
    assert_memory_equal(fake_uart_take(), "$C,3,", 5);
    advance_and_poll(VEC_PERIOD_MS / 2u); /* back on the original grid */
    assert_memory_equal(fake_uart_take(), "$C,4,", 5);
}

static void test_App_ShouldStartTheWatchdogAndKickItOnEveryPass(void **state)
{
    (void)state;
    assert_int_equal(fake_watchdog_timeout_ms, BOX_WATCHDOG_MS);
    uint32_t before = fake_watchdog_kicks;
    for (int i = 0; i < 10; i++) {
        advance_and_poll(1);
    }
    assert_int_equal(fake_watchdog_kicks - before, 10);
}

static void test_App_ShouldFlagEveryLineAfterAWatchdogReset(void **state)
{
    (void)state;
    fake_board_reset();
    fake_reset_by_watchdog = true;
    app_init();
    char payload[300];
    for (int i = 0; i < 3; i++) {
        load_vector(i);
        advance_and_poll(VEC_PERIOD_MS);
        next_line(fake_uart_take(), payload, sizeof payload);
        sample_line_t s;
        parse_sample(payload, &s);
        assert_int_equal(s.status, vec_status[i] | 0x0100u);
    }
}

static void test_App_ShouldAnswerInfoWithTheModelIdentity(void **state)
{
    (void)state;
    fake_uart_send("INFO\r\n");
    app_poll();
    char payload[300];
    assert_string_equal(next_line(fake_uart_take(), payload, sizeof payload), "");
    assert_string_equal(payload, "I," BOX_FW_VERSION "," VEC_MODEL_HASH ",OK," VEC_INFO_TAIL);
}

static void test_App_ShouldAnswerStatusWithPerChannelFaults(void **state)
{
    (void)state;
    fake_uart_send("STATUS\n");
    app_poll();
    char payload[300];
    next_line(fake_uart_take(), payload, sizeof payload);
    /* Before any sample: NO_DATA, seq 0, uptime 5 s, no channel faults yet. */
    assert_string_equal(payload, "S,0200,0,5,0000;0000;0000;0000;0000;0000;0000;0000,-," VEC_SVC_IDLE);

    load_vector(0);
    max31856_sim_set_fault(&fake_chips[1], 0x01); /* OPEN */
    fake_chips[3].present = false;                /* no answer */
    max31856_sim_set_temperature(&fake_chips[6], 201 * 128); /* above 200 degC: RANGE */
    advance_and_poll(VEC_PERIOD_MS);
    (void)fake_uart_take();
    fake_uart_send("STATUS\n");
    app_poll();
    next_line(fake_uart_take(), payload, sizeof payload);
    /* Every axis has a faulted input (dx: T02 open, T04 silent; dy: spindle out of range in
     * vector 0; dz: T07 out of range) and none had data yet: HOLD 0x002 | RANGE 0x010 |
     * OPEN 0x020 | TC_FAULT 0x040 | AUX_FAULT 0x080 | NO_DATA 0x200 = 0x02F2. Channel words:
     * SR OPEN 0x0001, NO_RESPONSE 0x0200, RANGE 0x0100. */
    assert_string_equal(payload, "S,02F2,0,6,0000;0001;0000;0200;0000;0000;0100;0000,-," VEC_SVC_IDLE);
}

static void test_App_ShouldReferenceFromTheFirstSampleAfterZero(void **state)
{
    (void)state;
    char payload[300];
    fake_uart_send("ZERO\n"); /* before any sample: seq 0, the reference starts at sample 0 */
    app_poll();
    next_line(fake_uart_take(), payload, sizeof payload);
    assert_string_equal(payload, "OK,ZERO,0");
    fake_uart_send("STATUS\n"); /* not in force before its first sample */
    app_poll();
    next_line(fake_uart_take(), payload, sizeof payload);
    assert_string_equal(payload + strlen(payload) - strlen(",-," VEC_SVC_IDLE), ",-," VEC_SVC_IDLE);
    for (int i = 0; i < 3; i++) {
        load_vector(i);
        advance_and_poll(VEC_PERIOD_MS);
        next_line(fake_uart_take(), payload, sizeof payload);
        sample_line_t s;
        parse_sample(payload, &s);
        assert_true(s.status & 0x0800u); /* REFERENCED */
    }
    fake_uart_send("STATUS\nZERO\n");
    app_poll();
    const char *rest = next_line(fake_uart_take(), payload, sizeof payload);
    assert_string_equal(payload + strlen(payload) - strlen(",0," VEC_SVC_IDLE), ",0," VEC_SVC_IDLE);
    next_line(rest, payload, sizeof payload);
    /* dy holds on samples 0-2 (spindle input out of range): a datum taken now would not be a
     * healthy box's, so ZERO is refused and the reference stays */
    assert_string_equal(payload, "E,HOLDING");
    load_vector(3);
    advance_and_poll(VEC_PERIOD_MS);
    (void)fake_uart_take();
    fake_uart_send("ZERO\n"); /* every axis computed at sample 3: accepted */
    app_poll();
    next_line(fake_uart_take(), payload, sizeof payload);
    assert_string_equal(payload, "OK,ZERO,3");
    load_vector(4);
    advance_and_poll(VEC_PERIOD_MS);
    (void)fake_uart_take();
    fake_uart_send("STATUS\n");
    app_poll();
    next_line(fake_uart_take(), payload, sizeof payload);
    assert_string_equal(payload + strlen(payload) - strlen(",4," VEC_SVC_IDLE), ",4," VEC_SVC_IDLE);
}

/* Every channel at 25 degC, T05 plus t05_extra; T07, the channel with a stuck check, reads
 * t07_code if not 0, else dithers by one code every sample as a live thermocouple does. */
static void steady_sample_t07(int32_t t05_extra, int32_t t07_code, sample_line_t *out)
{
    static uint32_t n;
    char payload[300];
    n++;
    for (int c = 0; c < VEC_N_CHANNELS; c++) {
        int32_t code = 25 * 128 + (c == 4 ? t05_extra : 0);
        if (c == VEC_STILL_CHANNEL) {
            code = t07_code != 0 ? t07_code : code + (int32_t)(n & 1u);
        }
        fake_chips[c].present = true;
        max31856_sim_set_temperature(&fake_chips[c], code);
        max31856_sim_set_fault(&fake_chips[c], 0);
    }
    fake_aux = 3000;
    fake_aux_ok = true;
    advance_and_poll(VEC_PERIOD_MS);
    next_line(fake_uart_take(), payload, sizeof payload);
    parse_sample(payload, out);
}

static void steady_sample(int32_t t05_extra, sample_line_t *out)
{
    steady_sample_t07(t05_extra, 0, out);
}

/* The STATUS reply's per-channel fault words and zero_seq: ",w0;w1;...;w7,-" */
static void status_words(char *payload, size_t cap)
{
    fake_uart_send("STATUS\n");
    app_poll();
    next_line(fake_uart_take(), payload, cap);
}

static void test_App_ShouldFlagAGlitchAndHoldTheChannelsLastGoodValue(void **state)
{
    (void)state;
    /* Every channel steady at 25 degC until the output has settled; then T05 (dy reads it,
     * 0.9 um/degC) reads +100 degC for one sample. */
    sample_line_t before, glitch, after;
    for (int i = 0; i < 200; i++) {
        steady_sample(0, &before);
    }
    assert_int_equal(before.status & 0x1006u, 0); /* settled: no IMPLAUSIBLE, HOLD, SLEW */
    steady_sample(12800, &glitch);
    char payload[300];
    fake_uart_send("STATUS\n");
    app_poll();
    next_line(fake_uart_take(), payload, sizeof payload);
    steady_sample(0, &after);
    assert_int_equal(glitch.status & 0x1000u, 0x1000u); /* IMPLAUSIBLE */
    assert_int_equal(glitch.status & 0x0002u, 0);       /* no HOLD: the axes keep correcting */
    assert_int_equal(glitch.codes[4], 25 * 128 + 12800); /* the line shows the code as read */
    /* channel 4's word: implausible (0x0400) */
    const char *words = ",0000;0000;0000;0000;0400;0000;0000;0000,-," VEC_SVC_IDLE;
    assert_string_equal(payload + strlen(payload) - strlen(words), words);
    assert_int_equal(after.status & 0x1000u, 0);
    /* the model got T05's last good value and its filters never saw the glitch: every axis
     * is exactly where it was (dz reads T07, which dithers: compare it two samples apart) */
    for (int a = 0; a < VEC_N_AXES; a++) {
        if (a != 2) {
            assert_int_equal(glitch.corr[a], before.corr[a]);
        }
        assert_int_equal(after.corr[a], before.corr[a]);
    }
}

static void test_App_ShouldFaultAStuckChannelUntilItMoves(void **state)
{
    (void)state;
    /* Settled with T07 dithering; then T07 (dz reads it) freezes at a code the dither never
     * produced: its k-th reading of that code is stuck from k = VEC_MAX_STILL on. */
    sample_line_t s, last_live;
    char payload[300];
    const int32_t frozen = 25 * 128 + 5;
    for (int i = 0; i < 200; i++) {
        steady_sample(0, &s);
    }
    assert_int_equal(s.status & 0x1006u, 0); /* settled */
    for (int k = 1; k < VEC_MAX_STILL; k++) {
        steady_sample_t07(0, frozen, &last_live);
        assert_int_equal(last_live.status & 0x0002u, 0); /* not yet: no HOLD */
    }
    for (int k = VEC_MAX_STILL; k < VEC_MAX_STILL + 3; k++) {
        steady_sample_t07(0, frozen, &s);
        assert_int_equal(s.status & 0x0002u, 0x0002u); /* HOLD: dz reads a stuck channel */
        assert_int_equal(s.corr[2], last_live.corr[2]);  /* dz holds its last good value */
        assert_int_equal(s.corr[0], last_live.corr[0]);  /* dx and dy go on (steady) */
        assert_int_equal(s.codes[VEC_STILL_CHANNEL], frozen); /* the line shows the code */
    }
    status_words(payload, sizeof payload);
    const char *stuck = ",0000;0000;0000;0000;0000;0000;1000;0000,-," VEC_SVC_IDLE; /* STUCK */
    assert_string_equal(payload + strlen(payload) - strlen(stuck), stuck);
    /* The code moves one LSB: judged by the guard against its last good reading (the frozen
     * code, plausible), accepted; the fault clears at once. */
    steady_sample_t07(0, frozen + 1, &s);
    assert_int_equal(s.status & 0x0002u, 0);
    status_words(payload, sizeof payload);
    const char *clear = ",0000;0000;0000;0000;0000;0000;0000;0000,-," VEC_SVC_IDLE;
    assert_string_equal(payload + strlen(payload) - strlen(clear), clear);
    /* A chip fault ends the run: the same code again afterwards counts from 1. */
    for (int k = 1; k < VEC_MAX_STILL; k++) {
        steady_sample_t07(0, frozen + 1, &s);
    }
    max31856_sim_set_fault(&fake_chips[VEC_STILL_CHANNEL], 0x01); /* one OPEN sample */
    advance_and_poll(VEC_PERIOD_MS);
    (void)fake_uart_take();
    for (int k = 1; k < VEC_MAX_STILL; k++) {
        steady_sample_t07(0, frozen + 1, &s);
        assert_int_equal(s.status & 0x0002u, 0);
    }
    steady_sample_t07(0, frozen + 1, &s);
    assert_int_equal(s.status & 0x0002u, 0x0002u);
}

static void test_App_ShouldEmitEveryNthSampleAfterRate(void **state)
{
    (void)state;
    fake_uart_send("RATE 3\r\n");
    app_poll();
    char payload[300];
    next_line(fake_uart_take(), payload, sizeof payload);
    assert_string_equal(payload, "OK,RATE,3");
    int emitted[9] = {0};
    for (int i = 0; i < 9; i++) {
        load_vector(i);
        advance_and_poll(VEC_PERIOD_MS);
        const char *out = fake_uart_take();
        if (*out != '\0') {
            sample_line_t s;
            next_line(out, payload, sizeof payload);
            parse_sample(payload, &s);
            assert_int_equal(s.seq, i);
            emitted[i] = 1;
        }
    }
    const int want[9] = {1, 0, 0, 1, 0, 0, 1, 0, 0};
    assert_memory_equal(emitted, want, sizeof want);
}

static void test_App_ShouldAnswerErrorsAndKeepSampling(void **state)
{
    (void)state;
    fake_uart_send("RATE 0\nhello\n\x01\x02\n");
    app_poll();
    char payload[300];
    const char *rest = fake_uart_take();
    rest = next_line(rest, payload, sizeof payload);
    assert_string_equal(payload, "E,BAD_ARG");
    rest = next_line(rest, payload, sizeof payload);
    assert_string_equal(payload, "E,UNKNOWN");
    rest = next_line(rest, payload, sizeof payload);
    assert_string_equal(payload, "E,BINARY");
    assert_string_equal(rest, "");
    load_vector(0);
    advance_and_poll(VEC_PERIOD_MS);
    assert_memory_equal(fake_uart_take(), "$C,0,", 5);
}

/* ---- MEAS (docs/protocol.md, docs/service.md): expectations from gen_test_model.py ------ */

static void meas(uint32_t axis, int32_t nm, uint32_t seq, char *payload, size_t cap)
{
    char cmd[64];
    snprintf(cmd, sizeof cmd, "MEAS %u %d %u\n", (unsigned)axis, (int)nm, (unsigned)seq);
    fake_uart_send(cmd);
    app_poll();
    next_line(fake_uart_take(), payload, cap);
}

static void expect_line(const char *payload, const char *fmt, ...)
{
    char want[300];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(want, sizeof want, fmt, ap);
    va_end(ap);
    assert_string_equal(payload, want);
}

/* Settled at 25 degC (dx tracks its model, P at p_max): the latest sample's seq and line. */
static uint32_t settle(sample_line_t *s, int n)
{
    for (int i = 0; i < n; i++) {
        steady_sample(0, s);
    }
    assert_int_equal(s->status & 0x1006u, 0);
    return s->seq;
}

static void test_App_ShouldApplyAReadingThroughTheStepLimit(void **state)
{
    (void)state;
    sample_line_t s, next, last[4];
    char payload[300];
    settle(&s, 196);
    for (int i = 0; i < 4; i++) {
        steady_sample(0, &last[i]); /* the model drifts slowly (lags): keep each sample's */
    }
    s = last[3];
    uint32_t seq = s.seq;
    /* dx's model value at seq is what the line carried (no reference, no bias, settled) */
    meas(0, s.corr[0] + 5000, seq, payload, sizeof payload);
    expect_line(payload, "M,0,%u,A,-,5000,%d,%d", (unsigned)seq, VEC_MEAS_BIAS1,
                VEC_MEAS_P1_NM2);
    steady_sample(0, &next); /* the bias reaches the output from the next sample on */
    assert_true(labs((long)next.corr[0] - s.corr[0] - VEC_MEAS_BIAS1) <= 200L); /* + the drift */
    assert_true(next.corr[0] - s.corr[0] <= 5000); /* within dx's 5 um step */
    status_words(payload, sizeof payload);
    char tail[64];
    snprintf(tail, sizeof tail, ",-,%d:5000:0:0;0:-:0:0;-", VEC_MEAS_BIAS1);
    assert_string_equal(payload + strlen(payload) - strlen(tail), tail);
    /* a reading of a sample 3 back is still remembered (against dx's model value then, plus
     * the bias now: innovation 0), 4 back is not, nor one not produced yet */
    meas(0, last[1].corr[0] + VEC_MEAS_BIAS1, last[1].seq, payload, sizeof payload);
    expect_line(payload, "M,0,%u,A,-,0,%d,%d", (unsigned)last[1].seq, VEC_MEAS_BIAS1,
                VEC_MEAS_P2_NM2);
    meas(0, last[0].corr[0], last[0].seq, payload, sizeof payload);
    expect_line(payload, "M,0,%u,R,SEQ,-,%d,%d", (unsigned)last[0].seq, VEC_MEAS_BIAS1,
                VEC_MEAS_P2_NM2);
    meas(0, s.corr[0], next.seq + 1u, payload, sizeof payload);
    expect_line(payload, "M,0,%u,R,SEQ,-,%d,%d", (unsigned)(next.seq + 1u), VEC_MEAS_BIAS1,
                VEC_MEAS_P2_NM2);
}

static void test_App_ShouldRefuseAChipOnTheArtifactAtTheGate(void **state)
{
    (void)state;
    sample_line_t s, next;
    char payload[300];
    uint32_t seq = settle(&s, 200);
    meas(0, s.corr[0] + 5000, seq, payload, sizeof payload);
    steady_sample(0, &s); /* the bias is in the line now (4.7 um < dx's 5 um step) */
    /* +50 um on the artifact: the innovation counts the bias already in force */
    meas(0, s.corr[0] - VEC_MEAS_BIAS1 + 50000, s.seq, payload, sizeof payload);
    expect_line(payload, "M,0,%u,R,GATE,%d,%d,%d", (unsigned)s.seq, VEC_MEAS_GATE_NU,
                VEC_MEAS_BIAS1, VEC_MEAS_P1_TICK_NM2);
    meas(0, s.corr[0] - VEC_MEAS_BIAS1 + 50000, s.seq, payload, sizeof payload);
    steady_sample(0, &next);
    assert_int_equal(next.corr[0], s.corr[0]); /* never moves the tool */
    status_words(payload, sizeof payload);
    char tail[64];
    snprintf(tail, sizeof tail, ",-,%d:%d:2:0;0:-:0:0;-", VEC_MEAS_BIAS1, VEC_MEAS_GATE_NU);
    assert_string_equal(payload + strlen(payload) - strlen(tail), tail); /* 2 refusals */
}

/* The gate's lock-out (docs/service.md, "Re-opening"): the third refused reading in a row that
 * agrees with the streak's first re-opens dx (REOPEN), also across a warm reset; one that does
 * not agree starts the streak again. The output walks to it through dx's 5 um step limit. */
static void test_App_ShouldReopenAfterRefusalsThatAgree(void **state)
{
    (void)state;
    sample_line_t s, next;
    char payload[300], tail[64];
    uint32_t seq = settle(&s, 200);
    meas(0, s.corr[0] + 5000, seq, payload, sizeof payload);
    steady_sample(0, &s);
    const int32_t base = (int32_t)(s.corr[0] - VEC_MEAS_BIAS1); /* dx's model value: bias 4.7 um in force */
    const int32_t offsets[4] = {50000, 90000, 50000, 50000}; /* +90 um does not agree */
    for (int i = 0; i < 4; i++) {
        meas(0, base + offsets[i], s.seq, payload, sizeof payload);
        expect_line(payload, "M,0,%u,R,GATE,%d,%d,%d", (unsigned)s.seq,
                    offsets[i] - VEC_MEAS_BIAS1, VEC_MEAS_BIAS1, VEC_MEAS_P1_TICK_NM2);
    }
    fake_reset_by_watchdog = true; /* the streak (2 agreeing) is retained */
    app_init();
    (void)fake_uart_take();
    steady_sample(0, &s);
    meas(0, s.corr[0] - VEC_MEAS_BIAS1 + 50000, s.seq, payload, sizeof payload);
    expect_line(payload, "M,0,%u,A,REOPEN,%d,%d,%d", (unsigned)s.seq, VEC_MEAS_GATE_NU,
                VEC_MEAS_REOPEN_BIAS, VEC_MEAS_REOPEN_P_NM2);
    steady_sample(0, &next);
    assert_int_equal(next.corr[0] - s.corr[0], 5000); /* one step limit, no more */
    assert_true((next.status & 0x0004u) != 0u);       /* SLEW: walking to the new estimate */
    status_words(payload, sizeof payload);
    snprintf(tail, sizeof tail, ",-,%d:%d:0:1;0:-:0:0;-", VEC_MEAS_REOPEN_BIAS,
             VEC_MEAS_GATE_NU);
    assert_string_equal(payload + strlen(payload) - strlen(tail), tail); /* 1 re-opening */
}

static void test_App_ShouldRefuseMeasWithAReason(void **state)
{
    (void)state;
    sample_line_t s;
    char payload[300];
    uint32_t seq = settle(&s, 200);
    meas(7, 0, seq, payload, sizeof payload);
    expect_line(payload, "M,7,%u,R,AXIS,-,-,-", (unsigned)seq);
    meas(2, 0, seq, payload, sizeof payload); /* dz has no service block */
    expect_line(payload, "M,2,%u,R,OFF,-,-,-", (unsigned)seq);
    /* dx holds: T02 (dx reads it) open */
    max31856_sim_set_fault(&fake_chips[1], 0x01);
    advance_and_poll(VEC_PERIOD_MS);
    (void)fake_uart_take();
    meas(0, 0, seq + 1u, payload, sizeof payload);
    expect_line(payload, "M,0,%u,R,HOLDING,-,0,%d", (unsigned)(seq + 1u), VEC_MEAS_PMAX_NM2);
    meas(0, 0, seq, payload, sizeof payload); /* a good sample, but dx holds now */
    expect_line(payload, "M,0,%u,R,HOLDING,-,0,%d", (unsigned)seq, VEC_MEAS_PMAX_NM2);
    /* ZERO: no reference until it is in force and averaged (BOX_ZERO_SAMPLES) */
    seq = settle(&s, 30);
    fake_uart_send("ZERO\n");
    app_poll();
    (void)fake_uart_take();
    meas(1, 0, seq, payload, sizeof payload);
    expect_line(payload, "M,1,%u,R,NO_REF,-,0,%d", (unsigned)seq, VEC_MEAS_PMAX_NM2);
    for (int i = 0; i < BOX_ZERO_SAMPLES; i++) {
        steady_sample(0, &s);
        meas(1, s.corr[1], s.seq, payload, sizeof payload);
        if (i + 1 < BOX_ZERO_SAMPLES) {
            expect_line(payload, "M,1,%u,R,NO_REF,-,0,%d", (unsigned)s.seq, VEC_MEAS_PMAX_NM2);
        }
    }
    /* the reference is complete at the K-th sample: dy's model value there is its line */
    expect_line(payload, "M,1,%u,A,-,0,0,%d", (unsigned)s.seq, VEC_MEAS_P1_NM2);
    meas(1, 0, s.seq - 1u, payload, sizeof payload); /* from before: still averaging */
    expect_line(payload, "M,1,%u,R,NO_REF,-,0,%d", (unsigned)(s.seq - 1u), VEC_MEAS_P1_NM2);
    fake_uart_send("MEAS 0 x 1\nMEAS 0 1\nMEAS 0 1 2 3\nMEAS 0 2147483648 1\n");
    app_poll();
    const char *rest = fake_uart_take();
    for (int i = 0; i < 4; i++) {
        rest = next_line(rest, payload, sizeof payload);
        assert_string_equal(payload, "E,BAD_ARG");
    }
}

static void test_App_ShouldKeepTheEstimateOverAWarmReset(void **state)
{
    (void)state;
    sample_line_t s, after;
    char payload[300], before_status[300];
    uint32_t seq = settle(&s, 200);
    meas(0, s.corr[0] + 5000, seq, payload, sizeof payload);
    status_words(before_status, sizeof before_status);
    fake_reset_by_watchdog = true; /* the estimate is retained at once, not at the next sample */
    app_init();
    (void)fake_uart_take();
    status_words(payload, sizeof payload);
    const char *svc_before = strrchr(before_status, ',');
    assert_string_equal(strrchr(payload, ','), svc_before); /* bias, innovation, refusals */
    steady_sample(0, &after);
    assert_int_equal(after.seq, seq + 1u);
    assert_true(labs((long)after.corr[0] - s.corr[0] - VEC_MEAS_BIAS1) <= 200L); /* + the drift */
    /* the samples before the reset are forgotten (SEQ); the bias is not */
    meas(0, after.corr[0], seq, payload, sizeof payload);
    expect_line(payload, "M,0,%u,R,SEQ,-,%d,%d", (unsigned)seq, VEC_MEAS_BIAS1,
                VEC_MEAS_P1_TICK_NM2);
    /* a cold boot forgets it */
    fake_retain_clear();
    app_init();
    (void)fake_uart_take();
    status_words(payload, sizeof payload);
    assert_string_equal(payload + strlen(payload) - strlen(VEC_SVC_IDLE), VEC_SVC_IDLE);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_App_ShouldMatchHostVectorsBitForBit, boot),
        cmocka_unit_test_setup(test_App_ShouldReopenAfterRefusalsThatAgree, boot),
        cmocka_unit_test_setup(test_App_ShouldResumeBitForBitAfterAWatchdogReset, boot),
        cmocka_unit_test_setup(test_App_ShouldBootColdWhenTheRetainedMemoryIsLost, boot),
        cmocka_unit_test_setup(test_App_ShouldRefuseResumeWhenThereIsNothingToContinue, boot),
        cmocka_unit_test_setup(test_App_ShouldSendTheBlockItKeepsOnSnap, boot),
        cmocka_unit_test_setup(test_App_ShouldRefuseLoadWhileItsOwnStateIsInUse, boot),
        cmocka_unit_test_setup(test_App_ShouldConfigureEveryChipForItsThermocoupleType, boot),
        cmocka_unit_test_setup(test_App_ShouldNotSampleBeforeThePeriodHasPassed, boot),
        cmocka_unit_test_setup(test_App_ShouldShowMissedPeriodsAsAGapInSeq, boot),
        cmocka_unit_test_setup(test_App_ShouldStartTheWatchdogAndKickItOnEveryPass, boot),
        cmocka_unit_test_setup(test_App_ShouldFlagEveryLineAfterAWatchdogReset, boot),
        cmocka_unit_test_setup(test_App_ShouldAnswerInfoWithTheModelIdentity, boot),
        cmocka_unit_test_setup(test_App_ShouldAnswerStatusWithPerChannelFaults, boot),
        cmocka_unit_test_setup(test_App_ShouldEmitEveryNthSampleAfterRate, boot),
        cmocka_unit_test_setup(test_App_ShouldAnswerErrorsAndKeepSampling, boot),
        cmocka_unit_test_setup(test_App_ShouldReferenceFromTheFirstSampleAfterZero, boot),
        cmocka_unit_test_setup(test_App_ShouldFlagAGlitchAndHoldTheChannelsLastGoodValue, boot),
        cmocka_unit_test_setup(test_App_ShouldFaultAStuckChannelUntilItMoves, boot),
        cmocka_unit_test_setup(test_App_ShouldApplyAReadingThroughTheStepLimit, boot),
        cmocka_unit_test_setup(test_App_ShouldRefuseAChipOnTheArtifactAtTheGate, boot),
        cmocka_unit_test_setup(test_App_ShouldRefuseMeasWithAReason, boot),
        cmocka_unit_test_setup(test_App_ShouldKeepTheEstimateOverAWarmReset, boot),
    };
    return cmocka_run_group_tests_name("app", tests, NULL, NULL);
}
