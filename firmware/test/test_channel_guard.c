/* Plausibility guard of one channel: glitch held, repeated implausible readings a fault,
 * recovery when the readings settle, reference forgotten after another fault. */
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
    expect(5010, GUARD_OK, 5010); /* calm 3: settled at the new level, accepted */
    expect(5015, GUARD_OK, 5015);
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
    expect(1900, GUARD_FAULT, 0);
    expect(1900, GUARD_FAULT, 0);
    expect(1900, GUARD_OK, 1900);
}

static void test_Guard_ShouldForgetItsReferenceAfterAnotherFault(void **state)
{
    (void)state;
    expect(1000, GUARD_OK, 1000);
    channel_guard_lost(&g); /* e.g. open thermocouple for an hour */
    expect(9000, GUARD_OK, 9000);
    expect(9005, GUARD_OK, 9005);
    /* also in the middle of an implausible run */
    expect(20000, GUARD_HELD, 9005);
    channel_guard_lost(&g);
    expect(20000, GUARD_OK, 20000);
}

static void test_Guard_ShouldFaultAtOnceWhenNIsOne(void **state)
{
    (void)state;
    int32_t model = 0;
    assert_int_equal(channel_guard_check(&g, 0, STEP, 1, &model), GUARD_OK);
    assert_int_equal(channel_guard_check(&g, 100, STEP, 1, &model), GUARD_FAULT);
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
        cmocka_unit_test_setup(test_Guard_ShouldForgetItsReferenceAfterAnotherFault, setup),
        cmocka_unit_test_setup(test_Guard_ShouldFaultAtOnceWhenNIsOne, setup),
        cmocka_unit_test_setup(test_Guard_ShouldBeOffWithoutALimit, setup),
        cmocka_unit_test_setup(test_Guard_ShouldHandleTheExtremeCodesWithoutOverflow, setup),
    };
    return cmocka_run_group_tests_name("channel_guard", tests, NULL, NULL);
}
