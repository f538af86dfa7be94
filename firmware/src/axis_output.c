#include "axis_output.h"

#include "status.h"

void axis_output_init(axis_output_t *a)
{
    a->out_nm = 0;
    a->has_output = false;
    a->walking = false;
    a->zeroing = false;
    a->ref_nm = 0;
    a->zero_n = 0;
    a->zero_sum = 0;
}

void axis_output_zero(axis_output_t *a)
{
    a->zeroing = true;
    a->zero_n = 0;
    a->zero_sum = 0;
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

int32_t axis_output_mean_nm(int64_t sum, uint32_t n)
{
    /* round(|sum| / n) = floor((2|sum| + n) / 2n). With |sum| <= n * 2^31 and n <= 32767 the
     * dividend is below 2^48 and the divisor below 2^16: long division in 16-bit digits needs
     * only 32-bit divisions (the Cortex-M4's UDIV; a 64-bit division would pull in a 700-byte
     * library routine). The remainder stays below the divisor, so (r << 16) fits 32 bits. */
    uint64_t mag = sum < 0 ? (uint64_t)0 - (uint64_t)sum : (uint64_t)sum;
    uint64_t dividend = 2u * mag + n;
    uint32_t divisor = 2u * n;
    uint64_t q = 0;
    uint32_t r = 0;
    for (int shift = 48; shift >= 0; shift -= 16) {
        uint32_t cur = (r << 16) | (uint32_t)((dividend >> shift) & 0xFFFFu);
        q = (q << 16) | (cur / divisor);
        r = cur % divisor;
    }
    return sum < 0 ? (int32_t)(-(int64_t)q) : (int32_t)q;
}

static int32_t clamp_nm(int64_t v, int32_t max_abs, uint16_t *flags)
{
    if (v > max_abs) {
        *flags |= STATUS_CLAMP;
        return max_abs;
    }
    if (v < -(int64_t)max_abs) {
        *flags |= STATUS_CLAMP;
        return -max_abs;
    }
    return (int32_t)v;
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

    if (a->zeroing) {
        a->zero_sum += computed_nm;
        a->zero_n++;
        int32_t ref = axis_output_mean_nm(a->zero_sum, a->zero_n);
        if (a->zero_n >= cfg->zero_samples) {
            a->zeroing = false;
        }
        if (a->has_output) {
            /* Re-base the limiter: the datum moved, the tool did not. */
            a->out_nm = clamp_nm((int64_t)a->out_nm - ((int64_t)ref - a->ref_nm),
                                 cfg->max_abs_nm, &flags);
        }
        a->ref_nm = ref;
    }

    int32_t target = clamp_nm((int64_t)computed_nm - a->ref_nm, cfg->max_abs_nm, &flags);

    if (!a->has_output) {
        a->has_output = true;
        if (!cfg->cold_start_slew) {
            a->out_nm = target;
            return flags;
        }
        a->walking = true; /* from out_nm == 0 */
    }
    int32_t step = cfg->track_step_nm;
    if (a->walking && cfg->step_nm < step) {
        step = cfg->step_nm;
    }
    /* Both values are within +-max_abs_nm < 2^31, so the difference fits int64 trivially. */
    int64_t diff = (int64_t)target - a->out_nm;
    if (diff <= step && diff >= -(int64_t)step) {
        a->out_nm = target;
        a->walking = false;
    } else {
        a->out_nm += diff > 0 ? step : -step;
        flags |= STATUS_SLEW;
    }
    return flags;
}
