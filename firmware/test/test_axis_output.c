/* Output conditioning: fault hold, slew-limited walk-back, clamp, cold start. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "axis_output.h"
#include "status.h"

static const axis_output_cfg_t CFG = {.max_abs_nm = 50000, .step_nm = 1000,
                                      .cold_start_slew = false};
static const axis_output_cfg_t CFG_COLD = {.max_abs_nm = 50000, .step_nm = 1000,
                                           .cold_start_slew = true};

static void test_AxisOutput_ShouldTrackTheModelWhenInputsAreValid(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    assert_int_equal(axis_output_update(&a, &CFG, true, 12345), 0);
    assert_int_equal(a.out_nm, 12345);
    /* Once settled, model changes pass through unlimited (thermal drift is slow by itself). */
    assert_int_equal(axis_output_update(&a, &CFG, true, -20000), 0);
    assert_int_equal(a.out_nm, -20000);
}

static void test_AxisOutput_ShouldOutputZeroWithNoDataBeforeTheFirstValidSample(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    assert_int_equal(axis_output_update(&a, &CFG, false, 777), STATUS_HOLD | STATUS_NO_DATA);
    assert_int_equal(a.out_nm, 0);
}

static void test_AxisOutput_ShouldHoldTheLastGoodValueDuringAFault(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    axis_output_update(&a, &CFG, true, 4000);
    for (int i = 0; i < 5; i++) {
        assert_int_equal(axis_output_update(&a, &CFG, false, 99999), STATUS_HOLD);
        assert_int_equal(a.out_nm, 4000);
    }
}

static void test_AxisOutput_ShouldWalkBackAtTheSlewLimitAfterAFault(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    axis_output_update(&a, &CFG, true, 4000);
    axis_output_update(&a, &CFG, false, 0);
    /* Model moved to 7500 meanwhile: 4000 -> 5000 -> 6000 -> 7000 -> 7500, never a jump. */
    const int32_t expected[] = {5000, 6000, 7000, 7500, 7500};
    const uint16_t flags[] = {STATUS_SLEW, STATUS_SLEW, STATUS_SLEW, 0, 0};
    for (int i = 0; i < 5; i++) {
        assert_int_equal(axis_output_update(&a, &CFG, true, 7500), flags[i]);
        assert_int_equal(a.out_nm, expected[i]);
    }
}

static void test_AxisOutput_ShouldWalkDownwardsToo(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    axis_output_update(&a, &CFG, true, 0);
    axis_output_update(&a, &CFG, false, 0);
    assert_int_equal(axis_output_update(&a, &CFG, true, -2500), STATUS_SLEW);
    assert_int_equal(a.out_nm, -1000);
    assert_int_equal(axis_output_update(&a, &CFG, true, -2500), STATUS_SLEW);
    assert_int_equal(a.out_nm, -2000);
    assert_int_equal(axis_output_update(&a, &CFG, true, -2500), 0);
    assert_int_equal(a.out_nm, -2500);
}

static void test_AxisOutput_ShouldKeepWalkingThroughAnotherFault(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    axis_output_update(&a, &CFG, true, 0);
    axis_output_update(&a, &CFG, false, 0);
    axis_output_update(&a, &CFG, true, 10000); /* 1000 */
    assert_int_equal(axis_output_update(&a, &CFG, false, 10000), STATUS_HOLD);
    assert_int_equal(a.out_nm, 1000);
    assert_int_equal(axis_output_update(&a, &CFG, true, 10000), STATUS_SLEW);
    assert_int_equal(a.out_nm, 2000);
}

static void test_AxisOutput_ShouldNeverJumpBetweenAFaultAndCatchingUp(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    /* A fixed pseudo-random sequence (LCG, seed 12345) of targets and faults. Property: from a
     * fault (or power-up) until the output has reached the clamped target, it moves at most
     * one step per sample; otherwise it equals the clamped target; it never leaves the clamp. */
    uint32_t x = 12345u;
    int32_t prev = a.out_nm;
    bool recovering = true; /* cold start walks from 0 */
    int walked = 0;
    for (int i = 0; i < 5000; i++) {
        x = x * 1103515245u + 12345u;
        bool valid = (x >> 28) != 0u; /* about 1 in 16 samples faulted */
        int32_t target = (int32_t)((x >> 8) % 120001u) - 60000;
        axis_output_update(&a, &CFG_COLD, valid, target);
        int32_t clamped = target > 50000 ? 50000 : (target < -50000 ? -50000 : target);
        if (!valid) {
            assert_int_equal(a.out_nm, prev);
            recovering = true;
        } else if (recovering) {
            int32_t d = a.out_nm - prev;
            assert_true(d <= 1000 && d >= -1000);
            walked++;
            recovering = a.out_nm != clamped;
        } else {
            assert_int_equal(a.out_nm, clamped);
        }
        assert_true(a.out_nm <= 50000 && a.out_nm >= -50000);
        prev = a.out_nm;
    }
    assert_true(walked > 1000); /* the property was exercised, not vacuous */
}

static void test_AxisOutput_ShouldClampToTheConfiguredMaximum(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    assert_int_equal(axis_output_update(&a, &CFG, true, 50001), STATUS_CLAMP);
    assert_int_equal(a.out_nm, 50000);
    assert_int_equal(axis_output_update(&a, &CFG, true, 50000), 0);
    assert_int_equal(axis_output_update(&a, &CFG, true, INT32_MIN), STATUS_CLAMP);
    assert_int_equal(a.out_nm, -50000);
}

static void test_AxisOutput_ShouldReportClampAndSlewTogether(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    axis_output_update(&a, &CFG, true, 0);
    axis_output_update(&a, &CFG, false, 0);
    assert_int_equal(axis_output_update(&a, &CFG, true, INT32_MAX), STATUS_CLAMP | STATUS_SLEW);
    assert_int_equal(a.out_nm, 1000);
}

static void test_AxisOutput_ShouldStartFromZeroAtTheSlewLimitWhenColdStartSlewIsOn(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    assert_int_equal(axis_output_update(&a, &CFG_COLD, true, 2400), STATUS_SLEW);
    assert_int_equal(a.out_nm, 1000);
    assert_int_equal(axis_output_update(&a, &CFG_COLD, true, 2400), STATUS_SLEW);
    assert_int_equal(a.out_nm, 2000);
    assert_int_equal(axis_output_update(&a, &CFG_COLD, true, 2400), 0);
    assert_int_equal(a.out_nm, 2400);
}

static void test_AxisOutput_ShouldConvertTheSlewRateToAStepPerPeriod(void **state)
{
    (void)state;
    assert_int_equal(axis_output_step_nm(1000, 1000), 1000); /* 1 um/s at 1 s */
    assert_int_equal(axis_output_step_nm(1000, 250), 250);
    assert_int_equal(axis_output_step_nm(1000, 60000), 60000);
    assert_int_equal(axis_output_step_nm(1, 100), 1); /* rounds 0.1 up to the 1 nm minimum */
    assert_int_equal(axis_output_step_nm(1500, 1), 2); /* 1.5 rounds half up */
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_AxisOutput_ShouldTrackTheModelWhenInputsAreValid),
        cmocka_unit_test(test_AxisOutput_ShouldOutputZeroWithNoDataBeforeTheFirstValidSample),
        cmocka_unit_test(test_AxisOutput_ShouldHoldTheLastGoodValueDuringAFault),
        cmocka_unit_test(test_AxisOutput_ShouldWalkBackAtTheSlewLimitAfterAFault),
        cmocka_unit_test(test_AxisOutput_ShouldWalkDownwardsToo),
        cmocka_unit_test(test_AxisOutput_ShouldKeepWalkingThroughAnotherFault),
        cmocka_unit_test(test_AxisOutput_ShouldNeverJumpBetweenAFaultAndCatchingUp),
        cmocka_unit_test(test_AxisOutput_ShouldClampToTheConfiguredMaximum),
        cmocka_unit_test(test_AxisOutput_ShouldReportClampAndSlewTogether),
        cmocka_unit_test(test_AxisOutput_ShouldStartFromZeroAtTheSlewLimitWhenColdStartSlewIsOn),
        cmocka_unit_test(test_AxisOutput_ShouldConvertTheSlewRateToAStepPerPeriod),
    };
    return cmocka_run_group_tests_name("axis_output", tests, NULL, NULL);
}
