/* docs/service.md, "Fixed point": the ranges quoted in the comments are proven there, from the
 * header's asserted parameter ranges (TCM_SVC_PARAMS_OK in model_eval.h). Where a range
 * allows, a value is held in 32 bits, so a product is one 32x32->64 multiply (flash). */
#include "estimator.h"

void est_tick(est_state_t *s, const tcm_service_t *p)
{
    int64_t next = s->p_q8 + p->q_q8; /* both < 2^38 */
    s->p_q8 = next < p->pmax_q8 ? next : p->pmax_q8;
}

/* The gate's test of v (|v| <= 2^23: an innovation, or the difference of two) against S. */
static bool passes(int32_t v, uint64_t sum, const tcm_service_t *p)
{
    const uint64_t v2 = (uint64_t)((int64_t)v * v); /* <= 2^46 */
    return (v2 << EST_GAIN_FRAC_BITS) <= p->g2_q8 * sum || /* <= 2^62, < 2^55 */
           v2 <= (uint64_t)p->floor2_nm2;
}

uint32_t est_measure(est_state_t *s, const tcm_service_t *p, int32_t z_nm, int32_t model_nm)
{
    const int64_t nu64 = (int64_t)z_nm - model_nm - s->bias_nm; /* |nu| < 2^33 */
    s->last_innovation_nm = nu64 > INT32_MAX   ? INT32_MAX
                            : nu64 < INT32_MIN ? INT32_MIN
                                               : (int32_t)nu64;
    if (nu64 > EST_INNOVATION_MAX_NM || nu64 < -EST_INNOVATION_MAX_NM) {
        s->agree = 0u;
        return EST_REFUSED;
    }
    const int32_t nu = (int32_t)nu64;             /* |nu| <= 2^22 */
    const uint64_t sum = (uint64_t)(s->p_q8 + p->r_q8); /* S = P + R: 1 .. 2^39 */
    if (!passes(nu, sum, p)) {
        /* the lock-out: refusals in a row that agree with the streak's first re-open */
        if (p->reopen_after == 0u) {
            return EST_REFUSED;
        }
        if (s->agree == 0u || !passes(nu - s->anchor_nm, sum, p)) { /* |d| <= 2^23 */
            s->anchor_nm = nu;
            s->agree = 0u;
        }
        if (++s->agree < p->reopen_after) {
            return EST_REFUSED;
        }
        /* re-open: the reading as it is (bias + nu, |.| < 2^23), its variance min(R, pmax) */
        const int32_t bias = s->bias_nm + nu;
        s->bias_nm = bias > EST_BIAS_MAX_NM ? EST_BIAS_MAX_NM
                                            : (bias < -EST_BIAS_MAX_NM ? -EST_BIAS_MAX_NM : bias);
        s->p_q8 = p->r_q8 < p->pmax_q8 ? p->r_q8 : p->pmax_q8;
        s->reopens = (uint16_t)(s->reopens + (s->reopens < UINT16_MAX));
        s->agree = 0u;
        return EST_REOPENED;
    }
    s->agree = 0u;
    /* K = P / S in Q16, rounded: (P * 2^16 + S/2) / S, 0 .. 2^16 since P < S. A restoring
     * division of its 17 quotient bits (S * 2^16 < 2^55, num < 2^55 + 2^38: no overflow), so
     * no 64-bit division helper of libgcc is linked. */
    uint64_t num = ((uint64_t)s->p_q8 << EST_GAIN_FRAC_BITS) + sum / 2u;
    uint64_t d = sum << EST_GAIN_FRAC_BITS;
    uint32_t k = 0u;
    for (uint32_t bit = UINT32_C(1) << EST_GAIN_FRAC_BITS; bit != 0u; bit >>= 1, d >>= 1) {
        if (d <= num) {
            num -= d;
            k |= bit;
        }
    }
    /* rdiv(K nu, 16): |K nu| <= 2^38, the result <= 2^22 in magnitude, |bias| + 2^22 fits */
    const int64_t kn = (int64_t)k * nu;
    const int64_t half = INT64_C(1) << (EST_GAIN_FRAC_BITS - 1);
    int32_t bias = s->bias_nm + (int32_t)(kn >= 0 ? (kn + half) >> EST_GAIN_FRAC_BITS
                                                  : -((-kn + half) >> EST_GAIN_FRAC_BITS));
    s->bias_nm = bias > EST_BIAS_MAX_NM ? EST_BIAS_MAX_NM
                                        : (bias < -EST_BIAS_MAX_NM ? -EST_BIAS_MAX_NM : bias);
    /* k P < 2^54 and >= 0: rdiv of a non-negative value; the result stays >= 0 (k <= 2^16) */
    s->p_q8 -= (int64_t)(((uint64_t)s->p_q8 * k + (uint64_t)half) >> EST_GAIN_FRAC_BITS);
    return EST_ACCEPTED;
}
