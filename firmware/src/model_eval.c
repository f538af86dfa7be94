/*
 * model_eval.c -- integer-only evaluation of a generated thermal model (TCM_RUNTIME_FORMAT below).
 *
 * The Python twin thermal_comp/codegen/fixed.py performs exactly the same operations; tests compare the
 * two bit for bit. Contract: docs/fixed-point.md; proofs of the bounds below: docs/codegen.md.
 *
 * Scaling and Overflow Behavior
 * -----------------------------
 * Inputs
 *   temperature code T  int32, 1/128 degC (Q7), valid iff in [min_code, max_code], a
 *                       sub-range of the chip's 19-bit range [-2^18, 2^18-1].
 *   aux value n         int32, rpm, valid iff in [min, max].
 * Filter state, int64, unit 2^-16/128 degC (code in Q16), one per distinct (channel, a): a
 * lag/rate term names it (term->state); terms of one channel and a share it on every axis:
 *   cold start          s = T * 65536 (a multiplication: a negative T is never shifted).
 *   update              d = T*65536 - s;  s = s + rdiv(d * a, 30),  1 <= a <= 2^30.
 *                       |rdiv(d*a, 30)| <= |d| and has the sign of d, so s stays between its
 *                       old value and T*65536: s is always within [min_code, max_code]*2^16.
 *                       Hence |d| <= (max_code - min_code)*2^16 and the generated header
 *                       asserts |d * a| <= 2^62, so the product and the rounding add fit.
 * Features x_j (int64): temp T; lag s; rate T*65536 - s; speed n; speed2 n*n;
 *   square (T - ref)^2 (the difference in int64); time min(k, time_max_samples).
 * Accumulator (per axis), int64:
 *   acc = intercept_q + sum_j coef_q[j] * x_j. The generator picks the shift F so that
 *   |intercept_q| + sum_j |coef_q[j]| * max|x_j| <= 2^62 over the declared ranges, and the
 *   header _Static_asserts it: every product and every partial sum fits int64 with one guard
 *   bit to spare, whatever the order of summation. No saturation is needed or done.
 * Output, int32 nanometres:
 *   out = rdiv(acc, F): one rounding, half away from zero, with no right shift of a negative
 *   value (rdiv(v) = -rdiv(-v) for v < 0). |acc| + 2^(F-1) <= 2^62 + 2^61 < 2^63. The header
 *   asserts rdiv(acc_max, F) <= INT32_MAX, so the conversion to int32_t is exact.
 * Faults: a channel that is not valid freezes its filter states and makes every axis that
 *   reads it skip this sample (output untouched, bit clear in the returned mask). When it is
 *   valid again after g missed samples, each of its filters is first updated over the gap
 *   with inputs last + rdiv_d((code - last) * k, g + 1), k = 1..min(g, TCM_CATCHUP_MAX)
 *   (division rounded half away from zero), then once with the new code: every such input
 *   lies between two valid codes, so the state bound below still holds. An input the
 *   caller marks valid but whose value is outside its declared range is treated as a fault,
 *   so no input can break the bounds above.
 * Error: |out - real-valued model| <= coefficient + state quantisation + 0.5 nm, written per
 *   axis in the header (TCM_AXISn_BOUND_PM) and in model.json.
 */
#include "model_eval.h"

/* v / 2^f rounded half away from zero; f <= 62, |v| <= 2^62 (callers guarantee both). */
static int64_t tcm_rdiv(int64_t v, uint8_t f)
{
    const int64_t half = (INT64_C(1) << f) >> 1; /* 2^(f-1), or 0 when f == 0 */
    if (v >= 0) {
        return (v + half) >> f;
    }
    return -((-v + half) >> f);
}

/* v / d (0 < d <= 2^16) rounded half away from zero; |v| < 2^35 here (a code difference of
 * less than 2^19 times k < 2^16). In 32-bit divisions, so no 64-bit division helper of libgcc
 * is linked (0.9 KiB of flash): u = 2|v| + d < 2^37 is divided by D = 2d <= 2^17 in two
 * base-2^15 digits. hi = u >> 15 < 2^22; the remainder hi % D < 2^17, shifted by 15 and with
 * the low 15 bits added, stays below 2^32. The quotient is below 2^19 (|v| / d < 2^19). */
static int64_t tcm_div_round(int64_t v, uint32_t d)
{
    const uint64_t u = 2u * (uint64_t)(v >= 0 ? v : -v) + d;
    const uint32_t dd = 2u * d;
    const uint32_t hi = (uint32_t)(u >> 15);
    const uint32_t lo = ((hi % dd) << 15) | (uint32_t)(u & 0x7FFFu);
    const int64_t q = (int64_t)(((hi / dd) << 15) + lo / dd);
    return v >= 0 ? q : -q;
}

/* One filter update towards code (Q16), as in tcm_step. */
static int64_t tcm_filter(int64_t s, int32_t code, uint32_t a)
{
    const int64_t d = (int64_t)code * INT64_C(65536) - s;
    return s + tcm_rdiv(d * (int64_t)a, TCM_ALPHA_FRAC_BITS);
}

/* Catch-up: the channel was missing for gap samples; run the filter over them with inputs
 * interpolated between the last valid reading and the new one (at most TCM_CATCHUP_MAX).
 * Every input lies between two valid codes, so the state bounds of the header still hold. */
static int64_t tcm_catch_up(int64_t s, int32_t last, int32_t code, uint16_t gap, uint32_t a)
{
    const uint32_t g = gap < TCM_CATCHUP_MAX ? gap : TCM_CATCHUP_MAX; /* gap <= 65535 */
    const int64_t diff = (int64_t)code - last;
    for (uint32_t k = 1u; k <= g; ++k) {
        const int64_t x = (int64_t)last + tcm_div_round(diff * (int64_t)k, g + 1u);
        s = tcm_filter(s, (int32_t)x, a);
    }
    return s;
}

void tcm_state_init(tcm_state_t *state)
{
    for (uint32_t i = 0; i < TCM_MAX_STATES; ++i) {
        state->s[i] = 0;
        state->last[i] = 0;
        state->gap[i] = 0u;
    }
    state->started = 0u;
    state->k = 0u;
}

/* ---- CRC-32 (IEEE 802.3, reflected, init and final xor 0xFFFFFFFF: zlib.crc32) ---------- */

static uint32_t crc_u8(uint32_t crc, uint8_t b)
{
    crc ^= b;
    for (int i = 0; i < 8; ++i) {
        crc = (crc >> 1) ^ (UINT32_C(0xEDB88320) & (0u - (crc & 1u)));
    }
    return crc;
}

static uint32_t crc_le(uint32_t crc, uint64_t v, int n_bytes)
{
    for (int i = 0; i < n_bytes; ++i) {
        crc = crc_u8(crc, (uint8_t)(v >> (8 * i)));
    }
    return crc;
}

/* Signed values are serialised as their two's complement bits (conversion to unsigned). */
static uint32_t crc_i32(uint32_t crc, int32_t v) { return crc_le(crc, (uint32_t)v, 4); }
static uint32_t crc_i64(uint32_t crc, int64_t v) { return crc_le(crc, (uint64_t)v, 8); }

uint32_t tcm_model_crc32(const tcm_model_t *m)
{
    uint32_t crc = UINT32_C(0xFFFFFFFF);
    crc = crc_le(crc, m->n_channels, 4);
    crc = crc_le(crc, m->n_aux, 4);
    crc = crc_le(crc, m->n_axes, 4);
    crc = crc_le(crc, m->period_ms, 4);
    for (uint32_t c = 0; c < m->n_channels; ++c) {
        crc = crc_i32(crc, m->channels[c].min_code);
        crc = crc_i32(crc, m->channels[c].max_code);
        crc = crc_i32(crc, m->channels[c].window_lo_code);
        crc = crc_i32(crc, m->channels[c].window_hi_code);
        crc = crc_i32(crc, m->channels[c].max_step_code);
        crc = crc_u8(crc, m->channels[c].tc_type);
        crc = crc_le(crc, m->channels[c].max_still_samples, 2);
    }
    for (uint32_t k = 0; k < m->n_aux; ++k) {
        crc = crc_i32(crc, m->aux[k].min);
        crc = crc_i32(crc, m->aux[k].max);
    }
    uint32_t t = 0;
    for (uint32_t a = 0; a < m->n_axes; ++a) {
        const tcm_axis_t *ax = &m->axes[a];
        crc = crc_u8(crc, ax->shift);
        crc = crc_u8(crc, ax->n_terms);
        crc = crc_i64(crc, ax->intercept_q);
        crc = crc_i32(crc, ax->max_step_nm);
        const tcm_service_t *sv = &ax->service;
        /* on, p0_pmax, g2_q8, reopen_after (1 + 1 + 4 + 1 bytes), then the four int64 */
        crc = crc_le(crc, sv->on | (uint32_t)sv->p0_pmax << 8 | (uint64_t)sv->g2_q8 << 16 |
                              (uint64_t)sv->reopen_after << 48, 7);
        crc = crc_i64(crc, sv->q_q8);
        crc = crc_i64(crc, sv->r_q8);
        crc = crc_i64(crc, sv->floor2_nm2);
        crc = crc_i64(crc, sv->pmax_q8);
        for (uint32_t j = 0; j < ax->n_terms; ++j, ++t) {
            const tcm_term_t *term = &m->terms[t];
            crc = crc_u8(crc, term->kind);
            crc = crc_u8(crc, term->input);
            crc = crc_u8(crc, term->state);
            crc = crc_i32(crc, term->param);
            crc = crc_i64(crc, term->coef_q);
        }
    }
    return crc ^ UINT32_C(0xFFFFFFFF);
}

/* ---- Evaluation ---------------------------------------------------------------------- */

/* Bit i of mask; an index past the mask (only a corrupted table has one) reads as "faulted". */
static int bit_set(uint32_t mask, uint32_t i) { return i < 32u && ((mask >> i) & 1u) != 0u; }

static int is_filter(uint8_t kind) { return kind == TCM_KIND_LAG || kind == TCM_KIND_RATE; }

static int is_temperature(uint8_t kind)
{
    return kind == TCM_KIND_TEMP || is_filter(kind) || kind == TCM_KIND_SQUARE;
}

static int is_aux(uint8_t kind) { return kind == TCM_KIND_SPEED || kind == TCM_KIND_SPEED2; }

/* Feature x_j of one term (docs/fixed-point.md table); inputs already known valid. */
static int64_t feature(const tcm_term_t *term, const tcm_state_t *st,
                       const int32_t *temp_codes, const int32_t *aux)
{
    switch (term->kind) {
    case TCM_KIND_TEMP:
        return temp_codes[term->input];
    case TCM_KIND_LAG:
        return st->s[term->state];
    case TCM_KIND_RATE:
        return (int64_t)temp_codes[term->input] * INT64_C(65536) - st->s[term->state];
    case TCM_KIND_SPEED:
        return aux[term->input];
    case TCM_KIND_SPEED2:
        return (int64_t)aux[term->input] * (int64_t)aux[term->input];
    case TCM_KIND_SQUARE: {
        const int64_t e = (int64_t)temp_codes[term->input] - (int64_t)term->param;
        return e * e;
    }
    case TCM_KIND_TIME:
        return (int64_t)(st->k < (uint32_t)term->param ? st->k : (uint32_t)term->param);
    default:
        return 0; /* unreachable for a model that passed its CRC and _Static_asserts */
    }
}

uint32_t tcm_step(const tcm_model_t *m, tcm_state_t *st, const int32_t *temp_codes,
                  uint32_t valid_mask, const int32_t *aux, int32_t *out_nm)
{
    /* 1. Which inputs are usable this sample: flagged valid and inside the declared range. */
    uint32_t ch_ok = 0u;
    for (uint32_t c = 0; c < m->n_channels && c < TCM_MAX_CHANNELS; ++c) {
        const int32_t code = temp_codes[c];
        if (bit_set(valid_mask, c) && code >= m->channels[c].min_code &&
            code <= m->channels[c].max_code) {
            ch_ok |= UINT32_C(1) << c;
        }
    }
    uint32_t aux_ok = 0u;
    for (uint32_t k = 0; k < m->n_aux && k < TCM_MAX_AUX; ++k) {
        if (aux[k] >= m->aux[k].min && aux[k] <= m->aux[k].max) {
            aux_ok |= UINT32_C(1) << k;
        }
    }

    /* 2. Filter states of valid channels: cold start, then one update (frozen if faulted),
     * each state once, at the first term (in table order) that reads it. The walk uses the
     * axes' CRC-covered term counts, not the uncovered n_terms. */
    uint32_t n_terms = 0u;
    for (uint32_t a = 0; a < m->n_axes; ++a) {
        n_terms += m->axes[a].n_terms;
    }
    uint32_t updated = 0u;
    for (uint32_t t = 0; t < n_terms; ++t) {
        const tcm_term_t *term = &m->terms[t];
        if (!is_filter(term->kind) || term->state >= TCM_MAX_STATES) {
            continue;
        }
        const uint32_t bit = UINT32_C(1) << term->state;
        if ((updated & bit) != 0u) {
            continue; /* shared with an earlier term: already updated this sample */
        }
        updated |= bit;
        const uint32_t i = term->state;
        if (bit_set(ch_ok, term->input)) {
            const int32_t code = temp_codes[term->input];
            if ((st->started & bit) == 0u) {
                st->s[i] = (int64_t)code * INT64_C(65536);
                st->started |= bit;
            } else {
                if (st->gap[i] != 0u) {
                    st->s[i] = tcm_catch_up(st->s[i], st->last[i], code, st->gap[i], term->param);
                }
                st->s[i] = tcm_filter(st->s[i], code, term->param);
            }
            st->last[i] = code;
            st->gap[i] = 0u;
        } else if ((st->started & bit) != 0u && st->gap[i] != UINT16_MAX) {
            st->gap[i]++; /* frozen while missing; caught up when the channel is back */
        }
    }

    /* 3. Axes whose inputs are all valid: int64 dot product, one rounding. */
    uint32_t axes_ok = 0u;
    uint32_t t = 0u;
    for (uint32_t a = 0; a < m->n_axes && a < TCM_MAX_AXES; ++a) {
        const tcm_axis_t *ax = &m->axes[a];
        int64_t acc = ax->intercept_q;
        int valid = 1;
        for (uint32_t j = 0; j < ax->n_terms; ++j, ++t) {
            const tcm_term_t *term = &m->terms[t];
            if ((is_temperature(term->kind) && !bit_set(ch_ok, term->input)) ||
                (is_aux(term->kind) && !bit_set(aux_ok, term->input)) ||
                (is_filter(term->kind) && term->state >= TCM_MAX_STATES)) {
                valid = 0;
            }
            if (valid) {
                acc += term->coef_q * feature(term, st, temp_codes, aux);
            }
        }
        if (valid && ax->shift <= TCM_MAX_SHIFT) {
            out_nm[a] = (int32_t)tcm_rdiv(acc, ax->shift);
            axes_ok |= UINT32_C(1) << a;
        }
    }

    /* 4. The `time` term's sample counter (saturating; time_max_samples <= INT32_MAX). */
    if (st->k != UINT32_MAX) {
        ++st->k;
    }
    return axes_ok;
}
