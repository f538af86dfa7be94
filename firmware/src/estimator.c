/* docs/service.md, "Fixed point": the ranges quoted in the comments are proven there, from the
 * header's asserted parameter ranges (TCM_SVC_PARAMS_OK in model_eval.h). Where a range
 * allows, a value is held in 32 bits, so a product is one 32x32->64 multiply (flash). */
#include "estimator.h"

void est_tick(est_state_t *s, const tcm_service_t *p)
{
    int64_t next = s->p_q8 + p->q_q8; /* both < 2^38 */
    s->p_q8 = next < p->pmax_q8 ? next : p->pmax_q8;
}

bool est_measure(est_state_t *s, const tcm_service_t *p, int32_t z_nm, int32_t model_nm)
{
    const int64_t nu64 = (int64_t)z_nm - model_nm - s->bias_nm; /* |nu| < 2^33 */
    s->last_innovation_nm = nu64 > INT32_MAX   ? INT32_MAX
                            : nu64 < INT32_MIN ? INT32_MIN
                                               : (int32_t)nu64;
    if (nu64 > EST_INNOVATION_MAX_NM || nu64 < -EST_INNOVATION_MAX_NM) {
        return false;
    }
    const int32_t nu = (int32_t)nu64;             /* |nu| <= 2^22 */
    const uint64_t sum = (uint64_t)(s->p_q8 + p->r_q8); /* S = P + R: 1 .. 2^39 */
    const uint64_t nu2 = (uint64_t)((int64_t)nu * nu);  /* <= 2^44 */
    if ((nu2 << EST_GAIN_FRAC_BITS) > p->g2_q8 * sum && /* 2^60, < 2^55 */
        nu2 > (uint64_t)p->floor2_nm2) {
        return false;
    }
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
    return true;
}
