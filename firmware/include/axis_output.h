/* What the box actually sends for one axis, given what the model computed: an optional ZERO
 * reference, hold on a fault, a step limit per sample, a clamp. Pure logic, no HAL.
 *
 *   valid sample  -> (after ZERO) ref = mean of the first zero_samples valid computed values
 *                    target = clamp(computed - ref, +-max_abs_nm)          (CLAMP if cut)
 *                    out moves towards target by at most one step per sample (SLEW if cut):
 *                      step = track_step_nm while tracking (the model's per-axis limit),
 *                             min(step_nm, track_step_nm) while walking back
 *   fault         -> out unchanged (HOLD); walking resumes at the next valid sample
 *   never valid   -> out = 0 (HOLD | NO_DATA)
 * "Walking" starts after every hold and, with cold_start_slew, at power-up (from 0); it ends
 * when out reaches the target.
 * ZERO (axis_output_zero) starts a new reference: from the next valid sample on, ref is the
 * running mean of the computed values seen so far (so that sample outputs exactly 0), frozen
 * after zero_samples of them. Whenever ref changes by d, out (the limiter's state) moves by -d
 * too (saturating at +-max_abs_nm, CLAMP): a change of datum is never seen as a step. */
#ifndef AXIS_OUTPUT_H
#define AXIS_OUTPUT_H

#include <stdbool.h>
#include <stdint.h>

typedef struct {
    int32_t max_abs_nm;    /* clamp, > 0 */
    int32_t step_nm;       /* walk-back limit per sample period (BOX_SLEW_NM_PER_S), > 0 */
    int32_t track_step_nm; /* limit per sample period at all times (model), > 0 */
    uint32_t zero_samples; /* samples averaged into a ZERO reference, >= 1 */
    bool cold_start_slew;
} axis_output_cfg_t;

typedef struct {
    int32_t out_nm;
    bool has_output; /* a valid sample has been seen since power-up */
    bool walking;    /* out has not caught up with the computed value since the last hold */
    bool zeroing;    /* a ZERO reference is still being averaged */
    int32_t ref_nm;  /* the reference subtracted from the computed value (0 before ZERO) */
    uint32_t zero_n; /* samples in the reference so far */
    int64_t zero_sum;
} axis_output_t;

void axis_output_init(axis_output_t *a);

/* ZERO: the next valid samples build a new reference (the old one stays until the first). */
void axis_output_zero(axis_output_t *a);

/* Step one sample period; returns the STATUS_* bits this axis raises (HOLD, SLEW, CLAMP,
 * NO_DATA). The value to send is a->out_nm afterwards. */
uint16_t axis_output_update(axis_output_t *a, const axis_output_cfg_t *cfg, bool valid,
                            int32_t computed_nm);

#define AXIS_OUTPUT_MAX_SLEW_NM_PER_S (UINT32_C(1) << 22) /* 4.2 mm/s: far beyond any use */

/* Slew step per sample period for a rate in nm/s: rounded, at least 1 nm. */
int32_t axis_output_step_nm(uint32_t slew_nm_per_s, uint32_t period_ms);

/* sum / n rounded half away from zero, 1 <= n <= 32767, |sum| <= n * 2^31: the mean of a
 * ZERO reference. */
int32_t axis_output_mean_nm(int64_t sum, uint32_t n);

#endif
