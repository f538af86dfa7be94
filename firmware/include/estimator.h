/* The in-service estimator of one axis (issue 42): a scalar Kalman filter on a bias, the
 * correction a touch probe's readings teach the box on top of the model. Integers only,
 * bit-exact with thermal_comp/codegen/estimator.py; docs/service.md ("Fixed point") is the spec and the
 * proof of every range. Pure logic, no HAL; the application (app.c) decides which readings
 * reach it (MEAS, docs/protocol.md) and adds the bias to the model's value before the axis
 * output stage, so every change of the output still passes the step limit. */
#ifndef ESTIMATOR_H
#define ESTIMATOR_H

#include <stdbool.h>
#include <stdint.h>

#include "model_eval.h"

#define EST_P_FRAC_BITS 8            /* P, q and R in 1/256 nm^2 */
#define EST_GAIN_FRAC_BITS 16        /* K in Q16 */
#define EST_INNOVATION_MAX_NM (INT64_C(1) << 22) /* beyond: refused before any product */
#define EST_BIAS_MAX_NM INT32_C(500000)          /* |bias| is clamped to 0.5 mm */

/* What survives a warm reset (the application keeps it in its retained block). */
typedef struct {
    int64_t p_q8;               /* the bias's variance, 0 .. pmax_q8 */
    int32_t bias_nm;            /* added to the model's value, +-EST_BIAS_MAX_NM */
    int32_t last_innovation_nm; /* the last reading's innovation, saturated to int32 */
    int32_t anchor_nm;          /* the re-opening streak's first innovation, |.| <= 2^22 */
    uint16_t reopens;           /* re-openings since power-up or ZERO, saturating */
    uint8_t agree;              /* refused readings in that streak, 0 .. reopen_after */
} est_state_t;

/* est_measure's verdict */
#define EST_REFUSED 0u
#define EST_ACCEPTED 1u
#define EST_REOPENED 2u /* accepted: reopen_after agreeing refusals in a row (the lock-out) */

/* Power-up and ZERO (no function: the application clears every axis's state in one run of its
 * retained block, est_reset_all in app.c): bias 0, innovation 0, P = pmax_q8 when p0_pmax (no
 * start reference), else 0 (a start model: its output and the probe are both 0 there). */

/* Every sample after the reference sample, before its output: P = min(P + q, pmax). */
void est_tick(est_state_t *s, const tcm_service_t *p);

/* One reading z_nm of a sample whose referenced model value (before the bias) was model_nm:
 * EST_ACCEPTED if the gate accepted it (bias and P updated), EST_REFUSED if it refused it
 * (nothing but last_innovation_nm and the re-opening streak change), EST_REOPENED if it was
 * the reopen_after-th refused reading in a row agreeing with the streak's first (their
 * difference passes the gate): the bias takes the reading as it is, P = min(R, pmax)
 * (docs/service.md, "Re-opening"). */
uint32_t est_measure(est_state_t *s, const tcm_service_t *p, int32_t z_nm, int32_t model_nm);

/* P in nm^2 (rounded half up; P >= 0), for the MEAS reply: pmax < 2^38 / 2^8 fits 32 bits. */
#define EST_P_NM2(s) ((uint32_t)(((s)->p_q8 + (INT64_C(1) << (EST_P_FRAC_BITS - 1))) >> EST_P_FRAC_BITS))

#endif
