/* Plausibility guard of one channel: glitch held, repeated implausible readings a fault,
 * recovery when the readings settle within the time-grown allowance, the first reading after
 * another fault judged, a runaway faulted. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "channel_guard.h"

#define STEP 10
#define N 3

static channel_guard_t g;

static int setup(void **state)
{
    (void)state;
    channel_guard_init(&g);
    return 0;
}

/* Check one reading: the verdict and the code the model gets. */
static void expect(int32_t code, guard_result_t want, int32_t want_model)
{
    int32_t model = -999999;
    guard_result_t r = channel_guard_check(&g, code, STEP, N, &model);
    if (r != want) {
        fail_msg("reading %d: verdict %d, expected %d", (int)code, (int)r, (int)want);
    }
    if (want != GUARD_FAULT) {
        assert_int_equal(model, want_model);
    }
}

static void test_Guard_ShouldAcceptTheFirstReadingWhateverItIs(void **state)
{
    (void)state;
    expect(25000, GUARD_OK, 25000);
    expect(25010, GUARD_OK, 25010); /* exactly the limit is plausible */
    expect(25000, GUARD_OK, 25000);
}

static void test_Guard_ShouldHoldTheLastGoodValueForASingleGlitch(void **state)
{
    (void)state;
    expect(2560, GUARD_OK, 2560);
    expect(2560 + 12800, GUARD_HELD, 2560); /* +100 degC for one sample */
    expect(2565, GUARD_OK, 2565);           /* back: within 2 samples' worth of the limit */
    expect(2570, GUARD_OK, 2570);
}

static void test_Guard_ShouldAllowTheLimitPerSampleSinceTheLastGoodReading(void **state)
{
    (void)state;
    expect(0, GUARD_OK, 0);
    expect(11, GUARD_HELD, 0); /* 11 > 10 in one sample */
    expect(20, GUARD_OK, 20);  /* 20 <= 2 * 10 over two samples */
    expect(31, GUARD_HELD, 20);
    expect(41, GUARD_HELD, 20); /* 21 > 2 * 10 */
}

static void test_Guard_ShouldFaultAfterNImplausibleReadingsInARow(void **state)
{
    (void)state;
    expect(1000, GUARD_OK, 1000);
    expect(5000, GUARD_HELD, 1000);
    expect(5000, GUARD_HELD, 1000);
    expect(5000, GUARD_FAULT, 0); /* the third in a row: the channel is a fault */
    expect(5000, GUARD_FAULT, 0); /* calm 1 */
    expect(5005, GUARD_FAULT, 0); /* calm 2 */
    expect(5010, GUARD_FAULT, 0); /* calm 3, but 4010 from last good in 6 samples (60) */
}

static void test_Guard_ShouldAcceptANewLevelOnceTimeMakesItPlausible(void **state)
{
    (void)state;
    expect(1000, GUARD_OK, 1000);
    expect(1100, GUARD_HELD, 1000); /* +100 in one sample, limit 10 */
    expect(1100, GUARD_HELD, 1000);
    expect(1100, GUARD_FAULT, 0);
    for (int k = 4; k < 10; k++) {
        expect(1100, GUARD_FAULT, 0); /* settled, but 100 > 10 * k */
    }
    expect(1100, GUARD_OK, 1100); /* 10 samples since 1000: 100 <= 10 * 10 */
}

static void test_Guard_ShouldNeverRecoverOnANoisySensor(void **state)
{
    (void)state;
    expect(0, GUARD_OK, 0);
    for (int i = 0; i < 200; i++) {
        int32_t model = 0;
        guard_result_t r = channel_guard_check(&g, (i & 1) ? 3000 : -3000, STEP, N, &model);
        assert_int_equal(r, i < N - 1 ? GUARD_HELD : GUARD_FAULT);
    }
}

static void test_Guard_ShouldRestartTheCalmCountOnAnotherJump(void **state)
{
    (void)state;
    expect(0, GUARD_OK, 0);
    expect(900, GUARD_HELD, 0);
    expect(900, GUARD_HELD, 0);
    expect(900, GUARD_FAULT, 0);
    expect(900, GUARD_FAULT, 0);  /* calm 1 */
    expect(1900, GUARD_FAULT, 0); /* jump: calm 0 */
    expect(1900, GUARD_FAULT, 0); /* calm 1 */
    expect(1900, GUARD_FAULT, 0); /* calm 2 */
    for (int k = 8; k < 190; k++) {
        expect(1900, GUARD_FAULT, 0); /* calm, but 1900 > 10 * k since the last good 0 */
    }
    expect(1900, GUARD_OK, 1900); /* 190 samples: 1900 <= 1900 */
}

static void test_Guard_ShouldJudgeTheFirstReadingAfterAnotherFault(void **state)
{
    (void)state;
    expect(1000, GUARD_OK, 1000);
    channel_guard_lost(&g);           /* one OPEN sample: a loose connector */
    expect(1000 + 12800, GUARD_HELD, 1000); /* comes back +100 degC: not trusted */
    expect(1000 + 12800, GUARD_HELD, 1000);
    expect(1000 + 12800, GUARD_FAULT, 0);
    expect(1000 + 12800, GUARD_FAULT, 0);
}

static void test_Guard_ShouldGiveASensorBackAfterAnHourTheAllowanceOfAnHour(void **state)
{
    (void)state;
    expect(1000, GUARD_OK, 1000);
    for (int k = 0; k < 60; k++) {
        channel_guard_lost(&g); /* open thermocouple for 60 samples */
    }
    expect(1600, GUARD_OK, 1600); /* 600 in 61 samples: within 610 */
    channel_guard_lost(&g);
    expect(1621, GUARD_HELD, 1600); /* 21 in 2 samples: beyond 20 */
}

static void test_Guard_ShouldFaultARunawayThatStaysUnderTheStepLimit(void **state)
{
    (void)state;
    /* 9 codes per sample, each step under the limit of 10, but 36 in 4 samples is more than
     * 10 * (4 / 2 + 1) = 30: faster, for longer, than training ever moved */
    expect(0, GUARD_OK, 0);
    expect(9, GUARD_OK, 9);
    expect(18, GUARD_OK, 18);
    expect(27, GUARD_OK, 27);
    expect(36, GUARD_FAULT, 0); /* 36 - 0 = 36 > 30 over the last 4 samples */
    for (int k = 5; k < 40; k++) {
        expect(9 * k, GUARD_FAULT, 0); /* still running away: never accepted */
    }
}

static void test_Guard_ShouldAcceptASteadyChangeOfTheTrainedRate(void **state)
{
    (void)state;
    for (int k = 0; k < 100; k++) {
        expect(7 * k, GUARD_OK, 7 * k); /* 28 in 4 samples: within 30 */
    }
}

static void test_Guard_ShouldFaultAtOnceWhenNIsOne(void **state)
{
    (void)state;
    int32_t model = 0;
    assert_int_equal(channel_guard_check(&g, 0, STEP, 1, &model), GUARD_OK);
    assert_int_equal(channel_guard_check(&g, 100, STEP, 1, &model), GUARD_FAULT);
    for (int k = 2; k < 10; k++) {
        assert_int_equal(channel_guard_check(&g, 100, STEP, 1, &model), GUARD_FAULT);
    }
    assert_int_equal(channel_guard_check(&g, 100, STEP, 1, &model), GUARD_OK);
    assert_int_equal(model, 100);
}

static void test_Guard_ShouldBeOffWithoutALimit(void **state)
{
    (void)state;
    int32_t model = 0;
    assert_int_equal(channel_guard_check(&g, 0, 0, N, &model), GUARD_OK);
    assert_int_equal(channel_guard_check(&g, 262143, 0, N, &model), GUARD_OK);
    assert_int_equal(model, 262143);
}

static void test_Guard_ShouldHandleTheExtremeCodesWithoutOverflow(void **state)
{
    (void)state;
    int32_t model = 0;
    assert_int_equal(channel_guard_check(&g, INT32_MIN, 1, 255, &model), GUARD_OK);
    assert_int_equal(channel_guard_check(&g, INT32_MAX, 1, 255, &model), GUARD_HELD);
    assert_int_equal(model, INT32_MIN);
    assert_int_equal(channel_guard_check(&g, INT32_MIN, INT32_MAX, 255, &model), GUARD_OK);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_Guard_ShouldAcceptTheFirstReadingWhateverItIs, setup),
        cmocka_unit_test_setup(test_Guard_ShouldHoldTheLastGoodValueForASingleGlitch, setup),
        cmocka_unit_test_setup(test_Guard_ShouldAllowTheLimitPerSampleSinceTheLastGoodReading,
                               setup),
        cmocka_unit_test_setup(test_Guard_ShouldFaultAfterNImplausibleReadingsInARow, setup),
        cmocka_unit_test_setup(test_Guard_ShouldNeverRecoverOnANoisySensor, setup),
        cmocka_unit_test_setup(test_Guard_ShouldRestartTheCalmCountOnAnotherJump, setup),
        cmocka_unit_test_setup(test_Guard_ShouldAcceptANewLevelOnceTimeMakesItPlausible, setup),
        cmocka_unit_test_setup(test_Guard_ShouldJudgeTheFirstReadingAfterAnotherFault, setup),
        cmocka_unit_test_setup(test_Guard_ShouldGiveASensorBackAfterAnHourTheAllowanceOfAnHour,
                               setup),
        cmocka_unit_test_setup(test_Guard_ShouldFaultARunawayThatStaysUnderTheStepLimit, setup),
        cmocka_unit_test_setup(test_Guard_ShouldAcceptASteadyChangeOfTheTrainedRate, setup),
        cmocka_unit_test_setup(test_Guard_ShouldFaultAtOnceWhenNIsOne, setup),
        cmocka_unit_test_setup(test_Guard_ShouldBeOffWithoutALimit, setup),
        cmocka_unit_test_setup(test_Guard_ShouldHandleTheExtremeCodesWithoutOverflow, setup),
    };
    return cmocka_run_group_tests_name("channel_guard", tests, NULL, NULL);
}
