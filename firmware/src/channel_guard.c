#include "channel_guard.h"

void channel_guard_init(channel_guard_t *g)
{
    *g = (channel_guard_t){0};
}

static void tick(channel_guard_t *g)
{
    if (g->since < UINT16_MAX) {
        g->since++;
    }
}

void channel_guard_lost(channel_guard_t *g)
{
    if (g->has_ref) {
        tick(g);
    }
    g->run_n = 0; /* the run of consecutive readings is broken */
    g->calm = 0;
}

static int64_t abs_diff(int32_t a, int32_t b)
{
    int64_t d = (int64_t)a - (int64_t)b;
    return d < 0 ? -d : d;
}

static void push(channel_guard_t *g, int32_t code)
{
    if (g->run_n == GUARD_RUNAWAY_SAMPLES) {
        for (uint32_t i = 1; i < GUARD_RUNAWAY_SAMPLES; i++) {
            g->run[i - 1u] = g->run[i];
        }
        g->run_n--;
    }
    g->run[g->run_n++] = code;
}

/* The reading, after GUARD_RUNAWAY_SAMPLES consecutive ones, moved faster than training. */
static bool runaway(const channel_guard_t *g, int32_t code, int32_t max_step)
{
    return g->run_n == GUARD_RUNAWAY_SAMPLES &&
           abs_diff(code, g->run[0]) >
               (int64_t)max_step * (int64_t)(GUARD_RUNAWAY_SAMPLES / 2u + 1u);
}

static guard_result_t accept(channel_guard_t *g, int32_t code, int32_t *model_code)
{
    g->last_good = code;
    g->has_ref = true;
    g->faulted = false;
    g->since = 0;
    g->bad_run = 0;
    g->calm = 0;
    push(g, code);
    *model_code = code;
    return GUARD_OK;
}

static guard_result_t fault(channel_guard_t *g, int32_t code)
{
    g->faulted = true;
    g->calm = 0;
    g->prev = code;
    push(g, code); /* a runaway's readings stay in run[]: it must stop before recovery */
    return GUARD_FAULT;
}

guard_result_t channel_guard_check(channel_guard_t *g, int32_t code, int32_t max_step,
                                   uint8_t fault_after, int32_t *model_code)
{
    if (max_step <= 0 || !g->has_ref) {
        return accept(g, code, model_code);
    }
    tick(g);
    /* since <= 65535 and max_step < 2^31: the allowance fits int64. */
    int64_t allowed = (int64_t)max_step * (int64_t)g->since;
    if (g->faulted) {
        /* Recover once the readings are self-consistent again, plausible against the last
         * good one and no runaway (a noisy or drifting sensor never is). */
        if (g->run_n > 0u && abs_diff(code, g->prev) <= max_step) {
            if (g->calm < UINT8_MAX) {
                g->calm++;
            }
        } else {
            g->calm = 0;
        }
        bool ok = g->calm >= fault_after && abs_diff(code, g->last_good) <= allowed &&
                  !runaway(g, code, max_step);
        g->prev = code;
        push(g, code);
        if (ok) {
            return accept(g, code, model_code);
        }
        return GUARD_FAULT;
    }
    if (abs_diff(code, g->last_good) <= allowed) {
        if (runaway(g, code, max_step)) {
            /* The model saw the start of the run: go back to the reading before it. */
            g->last_good = g->run[0];
            g->since = (uint16_t)GUARD_RUNAWAY_SAMPLES;
            g->bad_run = 0;
            return fault(g, code);
        }
        return accept(g, code, model_code);
    }
    g->run_n = 0;
    g->bad_run++;
    if (g->bad_run >= fault_after) {
        return fault(g, code);
    }
    *model_code = g->last_good;
    return GUARD_HELD;
}
