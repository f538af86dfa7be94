/* docs/service.md, "Fixed point": the ranges quoted in the comments are proven there, from the
 * header's asserted parameter ranges (TCM_SVC_PARAMS_OK in model_eval.h). */
#include "estimator.h"

/* v / 2^f rounded half away from zero, never shifting a negative value (contract.fixed_point
 * .rdiv); |v| < 2^62. */
static int64_t est_rdiv(int64_t v, unsigned f)
{
    const int64_t half = (INT64_C(1) << f) >> 1;
    return v >= 0 ? (v + half) >> f : -((-v + half) >> f);
}

static int32_t sat32(int64_t v)
{
    return v > INT32_MAX ? INT32_MAX : (v < INT32_MIN ? INT32_MIN : (int32_t)v);
}

void est_reset(est_state_t *s, const tcm_service_t *p)
{
    s->bias_nm = 0;
    s->p_q8 = p->p0_pmax ? p->pmax_q8 : 0;
    s->last_innovation_nm = 0;
}

void est_tick(est_state_t *s, const tcm_service_t *p)
{
    int64_t next = s->p_q8 + p->q_q8; /* both < 2^38 */
    s->p_q8 = next < p->pmax_q8 ? next : p->pmax_q8;
}

bool est_measure(est_state_t *s, const tcm_service_t *p, int32_t z_nm, int32_t model_nm)
{
    const int64_t nu = (int64_t)z_nm - ((int64_t)model_nm + s->bias_nm); /* |nu| < 2^33 */
    s->last_innovation_nm = sat32(nu);
    if (nu > EST_INNOVATION_MAX_NM || nu < -EST_INNOVATION_MAX_NM) {
        return false;
    }
    const int64_t sum = s->p_q8 + p->r_q8;  /* S = P + R: 1 .. 2^39 */
    const uint64_t nu2 = (uint64_t)(nu * nu); /* <= 2^44 */
    if ((nu2 << EST_GAIN_FRAC_BITS) > (uint64_t)p->g2_q8 * (uint64_t)sum && /* 2^60, < 2^55 */
        nu2 > (uint64_t)p->floor2_nm2) {
        return false;
    }
    /* K = P / S in Q16, rounded: 0 .. 2^16 (P * 2^16 < 2^54) */
    const int64_t k = (int64_t)((((uint64_t)s->p_q8 << EST_GAIN_FRAC_BITS) +
                                 (uint64_t)sum / 2u) / (uint64_t)sum);
    int64_t bias = s->bias_nm + est_rdiv(k * nu, EST_GAIN_FRAC_BITS); /* |k nu| <= 2^38 */
    bias = bias > EST_BIAS_MAX_NM ? EST_BIAS_MAX_NM
                                  : (bias < -EST_BIAS_MAX_NM ? -EST_BIAS_MAX_NM : bias);
    s->bias_nm = (int32_t)bias;
    /* k P < 2^54 and >= 0: rdiv of a non-negative value; the result stays >= 0 (k <= 2^16) */
    s->p_q8 -= (k * s->p_q8 + (INT64_C(1) << (EST_GAIN_FRAC_BITS - 1))) >> EST_GAIN_FRAC_BITS;
    return true;
}
