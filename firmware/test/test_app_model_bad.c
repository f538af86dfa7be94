/* A model whose tables no longer match their CRC (one intercept changed by one LSB, as a
 * corrupted flash would): MODEL_BAD, no corrections, INFO says BAD, temperatures still read. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "app.h"
#include "box_config.h"
#include "fake_board.h"
#include "vectors.h"

static int boot(void **state)
{
    (void)state;
    fake_board_reset();
    app_init();
    return 0;
}

static void test_AppModelBad_ShouldSayCrcBadInInfo(void **state)
{
    (void)state;
    fake_uart_send("INFO\n");
    app_poll();
    const char *out = fake_uart_take();
    const char *want = "$I," BOX_FW_VERSION "," VEC_MODEL_HASH ",BAD,";
    assert_memory_equal(out, want, strlen(want));
}

static void test_AppModelBad_ShouldSendNoCorrectionsButKeepReportingTemperatures(void **state)
{
    (void)state;
    for (int i = 0; i < 5; i++) {
        for (int c = 0; c < VEC_N_CHANNELS; c++) {
            max31856_sim_set_temperature(&fake_chips[c], 2560 + 128 * c + i);
        }
        fake_aux = 1000;
        fake_now_ms += VEC_PERIOD_MS;
        app_poll();
        char want[200];
        /* MODEL_BAD only (no HOLD/NO_DATA: there are no axes to hold), 0 axes. */
        snprintf(want, sizeof want, "$C,%d,0001,0,8,%d,%d,%d,%d,%d,%d,%d,%d*", i, 2560 + i,
                 2688 + i, 2816 + i, 2944 + i, 3072 + i, 3200 + i, 3328 + i, 3456 + i);
        const char *out = fake_uart_take();
        assert_memory_equal(out, want, strlen(want));
    }
}

static void test_AppModelBad_ShouldReportModelBadInStatus(void **state)
{
    (void)state;
    fake_uart_send("STATUS\n");
    app_poll();
    const char *out = fake_uart_take();
    assert_memory_equal(out, "$S,0001,", 8);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_AppModelBad_ShouldSayCrcBadInInfo, boot),
        cmocka_unit_test_setup(test_AppModelBad_ShouldSendNoCorrectionsButKeepReportingTemperatures,
                               boot),
        cmocka_unit_test_setup(test_AppModelBad_ShouldReportModelBadInStatus, boot),
    };
    return cmocka_run_group_tests_name("app_model_bad", tests, NULL, NULL);
}
