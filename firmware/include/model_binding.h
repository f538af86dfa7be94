/* The one place the generated model.h is compiled in (src/model_binding.c): the rest of the
 * firmware reaches the model through these functions, so a test can link another model. */
#ifndef MODEL_BINDING_H
#define MODEL_BINDING_H

#include <stdint.h>

#include "model_eval.h"

const tcm_model_t *model_binding_model(void);
/* TCM_MODEL_CRC32: what tcm_model_crc32() must return for intact tables. */
uint32_t model_binding_expected_crc(void);
/* TCM_MODEL_HASH (16 hex digits). */
const char *model_binding_hash(void);
/* TCM_SAMPLE_PERIOD_MS: a compile-time copy, used even when the tables fail their CRC. */
uint32_t model_binding_period_ms(void);
/* TCM_ZERO_AT_POWERUP (codegen --zero-at-powerup): behave as if ZERO came before sample 0. */
int model_binding_zero_at_powerup(void);

#endif
