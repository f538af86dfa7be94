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
    uint64_t step = ((uint64_t)slew_nm_per_s * period_ms + 500u) / 1000u;
    if (step < 1u) {
        step = 1u;
    }
    if (step > (uint64_t)INT32_MAX) {
        step = (uint64_t)INT32_MAX;
    }
    return (int32_t)step;
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
