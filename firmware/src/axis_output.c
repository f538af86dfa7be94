#include "axis_output.h"

#include "status.h"

void axis_output_init(axis_output_t *a)
{
    a->out_nm = 0;
    a->has_output = false;
    a->walking = false;
}

int32_t axis_output_step_nm(uint32_t slew_nm_per_s, uint32_t period_ms)
{
    /* slew * period / 1000 rounded, in 32-bit pieces (no 64-bit division on the box):
     * whole seconds exactly, then the millisecond remainder (< 1000 * 2^22 < 2^32). */
    if (slew_nm_per_s > AXIS_OUTPUT_MAX_SLEW_NM_PER_S) {
        slew_nm_per_s = AXIS_OUTPUT_MAX_SLEW_NM_PER_S;
    }
    uint32_t whole_s = period_ms / 1000u;
    if (whole_s > (uint32_t)INT32_MAX / slew_nm_per_s) {
        return INT32_MAX;
    }
    uint32_t step = slew_nm_per_s * whole_s + (slew_nm_per_s * (period_ms % 1000u) + 500u) / 1000u;
    if (step > (uint32_t)INT32_MAX) {
        return INT32_MAX;
    }
    return step < 1u ? 1 : (int32_t)step;
}

uint16_t axis_output_update(axis_output_t *a, const axis_output_cfg_t *cfg, bool valid,
                            int32_t computed_nm)
{
    uint16_t flags = 0;
    if (!valid) {
        flags |= STATUS_HOLD;
        if (!a->has_output) {
            flags |= STATUS_NO_DATA;
        } else {
            a->walking = true;
        }
        return flags;
    }

    int32_t target = computed_nm;
    if (target > cfg->max_abs_nm) {
        target = cfg->max_abs_nm;
        flags |= STATUS_CLAMP;
    } else if (target < -cfg->max_abs_nm) {
        target = -cfg->max_abs_nm;
        flags |= STATUS_CLAMP;
    }

    if (!a->has_output) {
        a->has_output = true;
        a->walking = cfg->cold_start_slew; /* from out_nm == 0 */
    }
    if (!a->walking) {
        a->out_nm = target;
        return flags;
    }
    /* Both values are within +-max_abs_nm < 2^31, so the difference fits int64 trivially. */
    int64_t diff = (int64_t)target - a->out_nm;
    if (diff <= cfg->step_nm && diff >= -(int64_t)cfg->step_nm) {
        a->out_nm = target;
        a->walking = false;
    } else {
        a->out_nm += diff > 0 ? cfg->step_nm : -cfg->step_nm;
        flags |= STATUS_SLEW;
    }
    return flags;
}
