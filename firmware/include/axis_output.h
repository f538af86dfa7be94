/* What the box actually sends for one axis, given what the model computed: hold on a fault,
 * walk back at a limited rate afterwards, clamp to a maximum. Pure logic, no HAL.
 *
 *   valid sample  -> target = clamp(computed, +-max_abs_nm)            (CLAMP if it was cut)
 *                    tracking: out = target
 *                    walking:  out moves towards target by at most step_nm (SLEW while limited)
 *   fault         -> out unchanged (HOLD); walking resumes at the next valid sample
 *   never valid   -> out = 0 (HOLD | NO_DATA)
 * "Walking" starts after every hold and, with cold_start_slew, at power-up (from 0). */
#ifndef AXIS_OUTPUT_H
#define AXIS_OUTPUT_H

#include <stdbool.h>
#include <stdint.h>

typedef struct {
    int32_t max_abs_nm; /* clamp, > 0 */
    int32_t step_nm;    /* slew limit per sample period, > 0 */
    bool cold_start_slew;
} axis_output_cfg_t;

typedef struct {
    int32_t out_nm;
    bool has_output; /* a valid sample has been seen since power-up */
    bool walking;    /* out has not caught up with the computed value since the last hold */
} axis_output_t;

void axis_output_init(axis_output_t *a);

/* Step one sample period; returns the STATUS_* bits this axis raises (HOLD, SLEW, CLAMP,
 * NO_DATA). The value to send is a->out_nm afterwards. */
uint16_t axis_output_update(axis_output_t *a, const axis_output_cfg_t *cfg, bool valid,
                            int32_t computed_nm);

#define AXIS_OUTPUT_MAX_SLEW_NM_PER_S (UINT32_C(1) << 22) /* 4.2 mm/s: far beyond any use */

/* Slew step per sample period for a rate in nm/s: rounded, at least 1 nm. */
int32_t axis_output_step_nm(uint32_t slew_nm_per_s, uint32_t period_ms);

#endif
