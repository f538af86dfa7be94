#include "channel_guard.h"

void channel_guard_init(channel_guard_t *g)
{
    g->last_good = 0;
    g->prev = 0;
    g->bad_run = 0;
    g->calm = 0;
    g->has_ref = false;
    g->faulted = false;
}

void channel_guard_lost(channel_guard_t *g)
{
    channel_guard_init(g);
}

static int64_t abs_diff(int32_t a, int32_t b)
{
    int64_t d = (int64_t)a - (int64_t)b;
    return d < 0 ? -d : d;
}

static guard_result_t accept(channel_guard_t *g, int32_t code, int32_t *model_code)
{
    g->last_good = code;
    g->has_ref = true;
    g->faulted = false;
    g->bad_run = 0;
    g->calm = 0;
    *model_code = code;
    return GUARD_OK;
}

guard_result_t channel_guard_check(channel_guard_t *g, int32_t code, int32_t max_step,
                                   uint8_t fault_after, int32_t *model_code)
{
    if (max_step <= 0 || !g->has_ref) {
        return accept(g, code, model_code);
    }
    if (g->faulted) {
        /* Recover once the readings are self-consistent again (a swapped or re-mounted
         * sensor settles at a new level; a noisy one never does). */
        if (abs_diff(code, g->prev) <= max_step) {
            if (g->calm < UINT8_MAX) {
                g->calm++;
            }
        } else {
            g->calm = 0;
        }
        g->prev = code;
        if (g->calm >= fault_after) {
            return accept(g, code, model_code);
        }
        return GUARD_FAULT;
    }
    /* bad_run < fault_after <= 255 here, so samples since last_good fits comfortably. */
    int64_t allowed = (int64_t)max_step * ((int64_t)g->bad_run + 1);
    if (abs_diff(code, g->last_good) <= allowed) {
        return accept(g, code, model_code);
    }
    g->bad_run++;
    if (g->bad_run >= fault_after) {
        g->faulted = true;
        g->calm = 0;
        g->prev = code;
        return GUARD_FAULT;
    }
    *model_code = g->last_good;
    return GUARD_HELD;
}
