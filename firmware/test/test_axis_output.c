/* Output conditioning: fault hold, slew-limited walk-back, step limit while tracking, clamp,
 * cold start, ZERO reference. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "axis_output.h"
#include "status.h"

/* A tracking limit far above every step of the older tests: they see no change from it. */
static const axis_output_cfg_t CFG = {.max_abs_nm = 50000, .step_nm = 1000,
                                      .track_step_nm = 200000, .zero_samples = 4,
                                      .cold_start_slew = false};
static const axis_output_cfg_t CFG_COLD = {.max_abs_nm = 50000, .step_nm = 1000,
                                           .track_step_nm = 200000, .zero_samples = 4,
                                           .cold_start_slew = true};
/* The model's per-axis limit below the walk-back step, and above it. */
static const axis_output_cfg_t CFG_TRACK = {.max_abs_nm = 50000, .step_nm = 1000,
                                            .track_step_nm = 3000, .zero_samples = 4,
                                            .cold_start_slew = false};
static const axis_output_cfg_t CFG_TIGHT = {.max_abs_nm = 50000, .step_nm = 1000,
                                            .track_step_nm = 400, .zero_samples = 4,
                                            .cold_start_slew = false};

static void test_AxisOutput_ShouldTrackTheModelWhenInputsAreValid(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    assert_int_equal(axis_output_update(&a, &CFG, true, 12345), 0);
    assert_int_equal(a.out_nm, 12345);
    /* Once settled, model changes within the tracking limit pass through. */
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

static void test_AxisOutput_ShouldLimitEveryStepWhileTracking(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    assert_int_equal(axis_output_update(&a, &CFG_TRACK, true, 1000), 0);
    /* A glitch in the model output: +10 um in one sample. 1000 -> 4000 -> 7000 -> 10000 ->
     * 11000; then back down at the same limit. */
    const int32_t up[] = {4000, 7000, 10000, 11000};
    const uint16_t upf[] = {STATUS_SLEW, STATUS_SLEW, STATUS_SLEW, 0};
    for (int i = 0; i < 4; i++) {
        assert_int_equal(axis_output_update(&a, &CFG_TRACK, true, 11000), upf[i]);
        assert_int_equal(a.out_nm, up[i]);
    }
    assert_int_equal(axis_output_update(&a, &CFG_TRACK, true, 9000), 0);
    assert_int_equal(a.out_nm, 9000);
    assert_int_equal(axis_output_update(&a, &CFG_TRACK, true, -9000), STATUS_SLEW);
    assert_int_equal(a.out_nm, 6000);
}

static void test_AxisOutput_ShouldWalkBackAtTheSmallerOfBothLimits(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    axis_output_update(&a, &CFG_TIGHT, true, 0);
    axis_output_update(&a, &CFG_TIGHT, false, 0);
    /* after the hold: walk-back 1000 nm, model limit 400 nm: 400 wins */
    assert_int_equal(axis_output_update(&a, &CFG_TIGHT, true, 2000), STATUS_SLEW);
    assert_int_equal(a.out_nm, 400);
    axis_output_init(&a);
    axis_output_update(&a, &CFG_TRACK, true, 0);
    axis_output_update(&a, &CFG_TRACK, false, 0);
    /* walk-back 1000, model limit 3000: the walk-back rate after a hold */
    assert_int_equal(axis_output_update(&a, &CFG_TRACK, true, 5000), STATUS_SLEW);
    assert_int_equal(a.out_nm, 1000);
}

static void test_AxisOutput_ShouldLimitStepsAfterColdStartAndHold(void **state)
{
    (void)state;
    /* Property over a seeded sequence with faults: the output never moves by more than the
     * tracking limit per sample, and by no more than the walk-back step while walking. */
    axis_output_t a;
    axis_output_init(&a);
    axis_output_cfg_t cfg = CFG_TRACK;
    cfg.cold_start_slew = true;
    uint32_t x = 777u;
    int32_t prev = 0;
    int limited = 0;
    for (int i = 0; i < 5000; i++) {
        x = x * 1103515245u + 12345u;
        bool valid = (x >> 28) != 0u;
        int32_t target = (int32_t)((x >> 8) % 20001u) - 10000;
        uint16_t f = axis_output_update(&a, &cfg, valid, target);
        int32_t d = a.out_nm - prev;
        assert_true(d <= 3000 && d >= -3000);
        limited += (f & STATUS_SLEW) != 0;
        prev = a.out_nm;
    }
    assert_true(limited > 1000);
}

/* ---- ZERO ------------------------------------------------------------------------------ */

static void test_AxisOutput_ShouldRoundTheMeanHalfAwayFromZero(void **state)
{
    (void)state;
    assert_int_equal(axis_output_mean_nm(3, 2), 2);   /* 1.5 */
    assert_int_equal(axis_output_mean_nm(-3, 2), -2); /* -1.5 */
    assert_int_equal(axis_output_mean_nm(5, 4), 1);   /* 1.25 */
    assert_int_equal(axis_output_mean_nm(-7, 4), -2); /* -1.75 */
    assert_int_equal(axis_output_mean_nm(10, 3), 3);  /* 3.33 */
    assert_int_equal(axis_output_mean_nm(11, 3), 4);  /* 3.67 */
    assert_int_equal(axis_output_mean_nm(0, 7), 0);
    /* 3600 samples at the int32 extremes */
    assert_int_equal(axis_output_mean_nm((int64_t)INT32_MAX * 3600, 3600), INT32_MAX);
    assert_int_equal(axis_output_mean_nm((int64_t)INT32_MIN * 3600, 3600), INT32_MIN);
    /* against plain 64-bit arithmetic on the host, over seeded sums and counts */
    uint64_t x = 99u;
    for (int i = 0; i < 100000; i++) {
        x = x * 6364136223846793005u + 1442695040888963407u;
        uint32_t n = 1u + (uint32_t)((x >> 50) % 3600u);
        int64_t sum = (int64_t)(x >> 20) % ((int64_t)n * INT32_MAX);
        if (x & 1u) {
            sum = -sum;
        }
        int64_t mag = sum < 0 ? -sum : sum;
        int64_t want = (2 * mag + n) / (2 * (int64_t)n);
        assert_int_equal(axis_output_mean_nm(sum, n), sum < 0 ? -want : want);
    }
}

static void test_AxisOutput_ShouldOutputTheChangeSinceZero(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    axis_output_update(&a, &CFG, true, 20000);
    axis_output_zero(&a);
    /* computed 20100, 20300, 20200, 20500 (K = 4), then 21000:
     * ref 20100, 20200, 20200, 20275 (frozen); output 0, 100, 0, 225, 725 */
    const int32_t computed[] = {20100, 20300, 20200, 20500, 21000, 19000};
    const int32_t want[] = {0, 100, 0, 225, 725, -1275};
    const int32_t ref[] = {20100, 20200, 20200, 20275, 20275, 20275};
    for (int i = 0; i < 6; i++) {
        assert_int_equal(axis_output_update(&a, &CFG, true, computed[i]), 0);
        assert_int_equal(a.out_nm, want[i]);
        assert_int_equal(a.ref_nm, ref[i]);
    }
}

static void test_AxisOutput_ShouldLeaveHeldSamplesOutOfTheReference(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    axis_output_update(&a, &CFG, true, 5000);
    axis_output_zero(&a);
    /* held before the first reference sample: out keeps the old datum's value */
    assert_int_equal(axis_output_update(&a, &CFG, false, 99999), STATUS_HOLD);
    assert_int_equal(a.out_nm, 5000);
    /* first valid: ref 6000; the limiter state 5000 re-based by 6000: -1000, walking back
     * (after a hold) to 0 at 1000 nm: reaches it exactly */
    assert_int_equal(axis_output_update(&a, &CFG, true, 6000), 0);
    assert_int_equal(a.out_nm, 0);
    assert_int_equal(axis_output_update(&a, &CFG, false, 99999), STATUS_HOLD);
    assert_int_equal(axis_output_update(&a, &CFG, true, 6400), 0); /* ref 6200: out 200 */
    assert_int_equal(a.out_nm, 200);
    assert_int_equal(a.zero_n, 2u);
}

static void test_AxisOutput_ShouldNotSeeTheChangeOfDatumAsAStep(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    axis_output_update(&a, &CFG_TRACK, true, 30000);
    axis_output_zero(&a);
    /* The model moves by 500 nm per sample; the datum change of 30 um is not limited. */
    assert_int_equal(axis_output_update(&a, &CFG_TRACK, true, 30500), 0);
    assert_int_equal(a.out_nm, 0);
    assert_int_equal(axis_output_update(&a, &CFG_TRACK, true, 31000), 0); /* ref 30750 */
    assert_int_equal(a.out_nm, 250);
    /* limiting continues in the new datum: a +20 um model step still moves 3 um a sample */
    assert_int_equal(axis_output_update(&a, &CFG_TRACK, true, 51000), STATUS_SLEW);
    /* ref (30500 + 31000 + 51000) / 3 = 37500: state re-based 250 - 6750 = -6500, +3000 */
    assert_int_equal(a.ref_nm, 37500);
    assert_int_equal(a.out_nm, -3500);
}

static void test_AxisOutput_ShouldStartAtZeroWhenZeroedBeforeTheFirstSample(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    axis_output_zero(&a); /* TCM_ZERO_AT_POWERUP */
    assert_int_equal(axis_output_update(&a, &CFG_COLD, false, 0), STATUS_HOLD | STATUS_NO_DATA);
    assert_int_equal(axis_output_update(&a, &CFG_COLD, true, 45000), 0);
    assert_int_equal(a.out_nm, 0);
    assert_int_equal(axis_output_update(&a, &CFG_COLD, true, 45800), 0); /* ref 45400 */
    assert_int_equal(a.out_nm, 400);
}

static void test_AxisOutput_ShouldReplaceTheReferenceOnASecondZero(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    axis_output_update(&a, &CFG, true, 1000);
    axis_output_zero(&a);
    for (int i = 0; i < 6; i++) {
        axis_output_update(&a, &CFG, true, 1000);
    }
    assert_int_equal(a.ref_nm, 1000);
    assert_false(a.zeroing);
    axis_output_zero(&a);
    assert_int_equal(axis_output_update(&a, &CFG, true, -4000), 0);
    assert_int_equal(a.ref_nm, -4000);
    assert_int_equal(a.out_nm, 0);
}

static void test_AxisOutput_ShouldClampTheReferencedValueAndTheRebasedState(void **state)
{
    (void)state;
    axis_output_t a;
    axis_output_init(&a);
    assert_int_equal(axis_output_update(&a, &CFG, true, 70000), STATUS_CLAMP); /* out 50000 */
    axis_output_zero(&a);
    /* ref 70000: the state 50000 - 70000 = -20000, target 0: a 20 um step in the new datum,
     * within the tracking limit */
    assert_int_equal(axis_output_update(&a, &CFG, true, 70000), 0);
    assert_int_equal(a.out_nm, 0);
    axis_output_zero(&a);
    /* ref -60000: state 0 + 60000 saturates at the clamp; target 0 */
    assert_int_equal(axis_output_update(&a, &CFG, true, -60000), STATUS_CLAMP);
    assert_int_equal(a.out_nm, 0);
    /* referenced values beyond the clamp are clamped */
    for (int i = 0; i < 3; i++) {
        axis_output_update(&a, &CFG, true, -60000);
    }
    assert_int_equal(axis_output_update(&a, &CFG, true, 0), STATUS_CLAMP);
    assert_int_equal(a.out_nm, 50000);
}

static void test_AxisOutput_ShouldKeepTheAbsoluteStepLimitAcrossZeros(void **state)
{
    (void)state;
    /* Property: with the clamp never reached, out + ref (the correction in the machine's
     * datum) never moves more than the tracking limit per sample, whatever the faults and
     * ZEROs; after K valid samples the reference is the rounded mean of them (computed here
     * independently). */
    axis_output_t a;
    axis_output_init(&a);
    axis_output_cfg_t cfg = CFG_TRACK;
    cfg.max_abs_nm = 2000000000;
    uint32_t x = 4242u;
    int64_t prev_abs = 0;
    int64_t sum = 0;
    int n = -1; /* valid samples since the last ZERO, -1: never zeroed */
    int zeros = 0;
    for (int i = 0; i < 20000; i++) {
        x = x * 1103515245u + 12345u;
        bool valid = (x >> 28) != 0u;
        if (((x >> 4) & 0xFFu) == 0u) {
            axis_output_zero(&a);
            sum = 0;
            n = 0;
            zeros++;
        }
        int32_t target = (int32_t)((x >> 8) % 200001u) - 100000;
        bool had_output = a.has_output; /* the first output is not a step (no cold start) */
        axis_output_update(&a, &cfg, valid, target);
        if (valid && n >= 0 && n < (int)cfg.zero_samples) {
            sum += target;
            n++;
        }
        if (n > 0) {
            int64_t mag = sum < 0 ? -sum : sum;
            int64_t mean = (2 * mag + n) / (2 * n);
            assert_int_equal(a.ref_nm, sum < 0 ? -mean : mean);
        }
        int64_t abs_now = (int64_t)a.out_nm + a.ref_nm;
        if (had_output) {
            assert_true(abs_now - prev_abs <= 3000 && prev_abs - abs_now <= 3000);
        }
        prev_abs = abs_now;
    }
    assert_true(zeros > 20);
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
        cmocka_unit_test(test_AxisOutput_ShouldLimitEveryStepWhileTracking),
        cmocka_unit_test(test_AxisOutput_ShouldWalkBackAtTheSmallerOfBothLimits),
        cmocka_unit_test(test_AxisOutput_ShouldLimitStepsAfterColdStartAndHold),
        cmocka_unit_test(test_AxisOutput_ShouldRoundTheMeanHalfAwayFromZero),
        cmocka_unit_test(test_AxisOutput_ShouldOutputTheChangeSinceZero),
        cmocka_unit_test(test_AxisOutput_ShouldLeaveHeldSamplesOutOfTheReference),
        cmocka_unit_test(test_AxisOutput_ShouldNotSeeTheChangeOfDatumAsAStep),
        cmocka_unit_test(test_AxisOutput_ShouldStartAtZeroWhenZeroedBeforeTheFirstSample),
        cmocka_unit_test(test_AxisOutput_ShouldReplaceTheReferenceOnASecondZero),
        cmocka_unit_test(test_AxisOutput_ShouldClampTheReferencedValueAndTheRebasedState),
        cmocka_unit_test(test_AxisOutput_ShouldKeepTheAbsoluteStepLimitAcrossZeros),
    };
    return cmocka_run_group_tests_name("axis_output", tests, NULL, NULL);
}
