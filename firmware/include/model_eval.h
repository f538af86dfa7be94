/*
 * model_eval.h -- fixed-point evaluation of a generated thermal model (TCM_RUNTIME_FORMAT below).
 *
 * The model itself is a generated header (`host codegen model.json -o model.h`) holding one
 * `static const tcm_model_t tcm_model`; exactly one firmware file includes it. This runtime
 * evaluates it with integer arithmetic only (no FPU, no allocation). The contract shared with
 * the Python twin `thermal_comp/codegen/fixed.py` is docs/fixed-point.md; what it leaves open is in
 * docs/codegen.md.
 *
 * Usage:
 *     #include "model.h"                      // defines tcm_model, includes this file
 *     static tcm_state_t st;
 *     if (tcm_model_crc32(&tcm_model) != TCM_MODEL_CRC32) { ...MODEL_BAD... }
 *     tcm_state_init(&st);
 *     every sample period (also when every channel is faulted, so that `time` counts):
 *         uint32_t ok = tcm_step(&tcm_model, &st, codes, valid_mask, aux, out_nm);
 *         // axis a was recomputed iff (ok >> a) & 1; otherwise out_nm[a] is untouched (hold)
 */
#ifndef TCM_MODEL_EVAL_H
#define TCM_MODEL_EVAL_H

#include <stddef.h>
#include <stdint.h>

/* A generated model.h must carry the same number (nanopb style check in the header). */
#define TCM_RUNTIME_FORMAT 7

/* Capacity of the runtime (state is statically sized; codegen refuses bigger models). */
#define TCM_MAX_CHANNELS 32u /* valid_mask is a uint32_t */
#define TCM_MAX_AUX 8u
#define TCM_MAX_AXES 32u   /* the returned axes mask is a uint32_t */
#define TCM_MAX_STATES 32u /* one int64_t per distinct (channel, a) filter */

/* Term kinds (docs/fixed-point.md). */
#define TCM_KIND_TEMP 0u
#define TCM_KIND_LAG 1u
#define TCM_KIND_RATE 2u
#define TCM_KIND_SPEED 3u
#define TCM_KIND_SPEED2 4u
#define TCM_KIND_SQUARE 5u
#define TCM_KIND_TIME 6u

/* Thermocouple types (serialised in the CRC). */
#define TCM_TC_K 0u
#define TCM_TC_J 1u

/* Number formats. */
#define TCM_TEMP_FRAC_BITS 7   /* temperature code LSB = 2^-7 degC = 1/128 degC */
#define TCM_STATE_FRAC_BITS 16 /* filter state = code * 2^16 */
#define TCM_ALPHA_FRAC_BITS 30 /* filter coefficient a = alpha * 2^30, 1 <= a <= 2^30 */
#define TCM_CODE_MIN INT32_C(-262144) /* 19-bit two's complement range of the chip */
#define TCM_CODE_MAX INT32_C(262143)
#define TCM_ACC_LIMIT INT64_C(0x4000000000000000) /* 2^62: |accumulator| bound, 1 guard bit */
#define TCM_MAX_SHIFT 62u

/*
 * Constant-expression helpers for the generated header's _Static_asserts: the compiler
 * re-derives each invariant from the very literals that fill the tables. A false claim either
 * fails the assert or overflows a constant expression (a compile error under -Werror).
 */
#define TCM_ABS64(v) ((int64_t)(v) < 0 ? -(int64_t)(v) : (int64_t)(v))
#define TCM_MAX64(a, b) ((int64_t)(a) > (int64_t)(b) ? (int64_t)(a) : (int64_t)(b))
/* max |x_j| over the declared input ranges, per kind (docs/codegen.md proves each). */
#define TCM_XMAX_TEMP(lo, hi) TCM_MAX64(TCM_ABS64(lo), TCM_ABS64(hi))
#define TCM_XMAX_LAG(lo, hi) (TCM_XMAX_TEMP(lo, hi) * INT64_C(65536))
#define TCM_XMAX_RATE(lo, hi) (((int64_t)(hi) - (int64_t)(lo)) * INT64_C(65536))
#define TCM_XMAX_SPEED(lo, hi) TCM_XMAX_TEMP(lo, hi)
#define TCM_XMAX_SPEED2(lo, hi) (TCM_XMAX_TEMP(lo, hi) * TCM_XMAX_TEMP(lo, hi))
#define TCM_XMAX_SQUARE(lo, hi, ref)                                                        \
    (TCM_MAX64(TCM_ABS64((int64_t)(lo) - (int64_t)(ref)),                                  \
               TCM_ABS64((int64_t)(hi) - (int64_t)(ref))) *                                \
     TCM_MAX64(TCM_ABS64((int64_t)(lo) - (int64_t)(ref)),                                  \
               TCM_ABS64((int64_t)(hi) - (int64_t)(ref))))
#define TCM_XMAX_TIME(tmax) ((int64_t)(tmax))
/* One term's share of the accumulator bound (a coefficient alone must also fit: xmax >= 1). */
#define TCM_ACC_TERM(coef_q, xmax) (TCM_ABS64(coef_q) * TCM_MAX64((xmax), 1))
/* Largest |d * a| of a filter update: |d| <= (hi - lo) * 2^16. */
#define TCM_FILTER_PRODUCT_MAX(lo, hi, a)                                                   \
    (((int64_t)(hi) - (int64_t)(lo)) * INT64_C(65536) * (int64_t)(a))
/* rdiv of a non-negative constant (identity for f = 0). */
#define TCM_RDIV_CONST(v, f) (((int64_t)(v) + ((INT64_C(1) << (f)) >> 1)) >> (f))

/* One thermocouple channel: the valid code range (a code outside it is a fault), the
 * training window (a valid code outside it is an extrapolation: status EXTRAP), the largest
 * plausible change per sample (a faster one is status IMPLAUSIBLE) and the stuck limit (the
 * same code that many samples in a row is channel fault STUCK); the application, not this
 * runtime, applies the last two. */
typedef struct {
    int32_t min_code;       /* ceil(min_c * 128) */
    int32_t max_code;       /* floor(max_c * 128) */
    int32_t window_lo_code; /* training range widened by 5 % of its span, in codes */
    int32_t window_hi_code; /* (the valid range when the model has no training range) */
    int32_t max_step_code;  /* codes per sample period, >= 1 (docs/codegen.md) */
    uint16_t max_still_samples; /* samples of one code in a row = stuck; 0: no stuck check */
    uint8_t tc_type;    /* TCM_TC_K / TCM_TC_J */
    const char *sensor; /* sensor name, for INFO (not part of the CRC) */
} tcm_channel_t;

/* One auxiliary input (spindle speed, rpm): a value outside [min, max] is a fault. */
typedef struct {
    int32_t min;
    int32_t max;
    const char *name; /* not part of the CRC */
} tcm_aux_t;

/* One term: x_j computed as in docs/fixed-point.md, contributes coef_q * x_j. */
typedef struct {
    uint8_t kind;   /* TCM_KIND_* */
    uint8_t input;  /* channel index (temp/lag/rate/square) or aux index (speed/speed2) */
    uint8_t state;  /* lag/rate: its filter state; terms with the same input and a share one */
    int32_t param;  /* lag/rate: a = alpha*2^30; square: ref code; time: time_max_samples */
    int64_t coef_q; /* nanometres per unit of x_j, times 2^shift */
} tcm_term_t;

/* The in-service estimator's parameters of one axis (issue 42, docs/service.md "Fixed
 * point"; the application's estimator.c runs it, this runtime only carries and CRC-checks
 * them). on == 0: the model has no service block for the axis, MEAS is refused (OFF). */
typedef struct {
    int64_t q_q8;       /* process noise per sample, 1/256 nm^2, 0 .. TCM_SVC_Q_Q8_MAX */
    int64_t r_q8;       /* the probe's variance, 1/256 nm^2, 1 .. TCM_SVC_R_Q8_MAX */
    int64_t floor2_nm2; /* gate_floor^2, nm^2, 0 .. 10^12 */
    int64_t pmax_q8;    /* the variance's cap, 1/256 nm^2, 1 .. TCM_SVC_PMAX_Q8_MAX */
    uint32_t g2_q8;     /* gate_sigma^2 in Q8, 2^8 .. 2^16 */
    uint8_t on;
    uint8_t p0_pmax; /* P at power-up / ZERO: 1 pmax_q8 (no start reference), 0 zero */
    uint8_t reopen_after; /* agreeing refusals in a row that re-open the axis, 0: never */
} tcm_service_t;

#define TCM_SVC_Q_Q8_MAX INT64_C(25600000000)     /* 100 um^2/h over <= 3600 s, < 2^35 */
#define TCM_SVC_R_Q8_MAX INT64_C(51200000000)     /* probe and residual noise 10 um each, < 2^36 */
#define TCM_SVC_FLOOR2_MAX INT64_C(1000000000000) /* gate floor 1000 um, < 2^40 */
#define TCM_SVC_PMAX_Q8_MAX INT64_C(256000000000) /* p_max 1000 um^2, < 2^38 */
/* The header's check of one axis's parameters (a service-less axis: all zero). */
#define TCM_SVC_PARAMS_OK(on, q, r, g2, f2, pmax, p0pmax, reopen)                            \
    ((on) == 0u ? ((q) == 0 && (r) == 0 && (g2) == 0u && (f2) == 0 && (pmax) == 0 &&           \
                   (p0pmax) == 0u && (reopen) == 0u)                                          \
                : ((on) == 1u && (q) >= 0 && (q) <= TCM_SVC_Q_Q8_MAX && (r) >= 1 &&             \
                   (r) <= TCM_SVC_R_Q8_MAX && (g2) >= 256u && (g2) <= 65536u && (f2) >= 0 &&    \
                   (f2) <= TCM_SVC_FLOOR2_MAX && (pmax) >= 1 && (pmax) <= TCM_SVC_PMAX_Q8_MAX && \
                   (p0pmax) <= 1u && (reopen) <= 255u))

/*
 * One output axis. Its terms are the next n_terms entries of tcm_model_t.terms (axes in
 * order, no gaps), derived, not stored. A lag/rate term names its filter state: the lags and
 * rates of one channel with one a (on any axis) share it, so it is updated once per sample
 * however many terms read it. Every value the arithmetic reads is covered by the CRC.
 */
typedef struct {
    uint8_t shift;       /* F: out_nm = rdiv(acc, F) */
    uint8_t n_terms;
    int64_t intercept_q; /* nanometres times 2^shift */
    int32_t max_step_nm; /* the output never steps more than this per sample period, >= 1 */
    const char *name;    /* e.g. "dz_um" (not part of the CRC) */
    tcm_service_t service; /* the in-service estimator (MEAS); after name: no padding */
} tcm_axis_t;

typedef struct {
    uint32_t n_channels;
    uint32_t n_aux;
    uint32_t n_axes;
    uint32_t n_terms;  /* total over all axes */
    uint32_t n_states; /* distinct filter states (lag/rate terms share them) */
    uint32_t period_ms;
    const tcm_channel_t *channels;
    const tcm_aux_t *aux; /* NULL when n_aux == 0 */
    const tcm_term_t *terms;
    const tcm_axis_t *axes;
} tcm_model_t;

/* Evaluation state: filter states and the sample counter. Zeroed by tcm_state_init. */
/* A filter whose channel comes back after a gap is first run over at most this many missed
 * samples, with inputs interpolated between its last valid reading and the new one. */
#define TCM_CATCHUP_MAX 65535u

typedef struct {
    int64_t s[TCM_MAX_STATES];    /* filter state, code * 2^16 units */
    int32_t last[TCM_MAX_STATES]; /* the last valid reading of the state's channel */
    uint16_t gap[TCM_MAX_STATES]; /* samples missed since then (saturating at 65535) */
    uint32_t started;             /* bit i: state i had its cold start (first valid sample) */
    uint32_t k;                /* samples since power-up, saturating at UINT32_MAX */
} tcm_state_t;

/* Power-up state: no filter started, sample counter 0. */
void tcm_state_init(tcm_state_t *state);

/* IEEE CRC-32 (zlib.crc32) of the model tables' serialisation (docs/fixed-point.md). */
uint32_t tcm_model_crc32(const tcm_model_t *model);

/*
 * One sample. temp_codes[n_channels]: 1/128 degC codes; channel c is valid iff bit c of
 * valid_mask is set AND its code lies in [min_code, max_code]. aux[n_aux] (may be NULL when
 * n_aux == 0): aux k is valid iff it lies in [min, max]. Updates the filter states of valid
 * channels (faulted channels' states stay frozen), then writes out_nm[a] for every axis whose
 * inputs are all valid and returns the mask of those axes; other out_nm entries are untouched.
 * Call exactly once per sample period: the `time` term counts calls.
 */
uint32_t tcm_step(const tcm_model_t *model, tcm_state_t *state, const int32_t *temp_codes,
                  uint32_t valid_mask, const int32_t *aux, int32_t *out_nm);

#endif /* TCM_MODEL_EVAL_H */
