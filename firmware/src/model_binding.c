/* Compiles the generated model header (MODEL=... on the make command line) into the firmware. */
#include "model_binding.h"

#include "box_config.h"
/* The generated header, by absolute path (MODEL=... in the Makefile). */
#ifndef BOX_MODEL_HEADER
#error "Build with -DBOX_MODEL_HEADER='\"path/to/model.h\"' (make MODEL=path/to/model.h)."
#endif
#include BOX_MODEL_HEADER

_Static_assert(TCM_N_CHANNELS <= BOX_MAX_CHANNELS, "model has more channels than chip selects");
_Static_assert(TCM_N_AXES <= BOX_MAX_AXES, "model has more axes than BOX_MAX_AXES");
_Static_assert(TCM_N_AUX <= BOX_MAX_AUX, "model has more aux inputs than BOX_MAX_AUX");
_Static_assert(TCM_SAMPLE_PERIOD_MS >= 1, "sample period must be at least 1 ms");
#ifndef TCM_ZERO_AT_POWERUP
#error "model.h has no TCM_ZERO_AT_POWERUP: regenerate it with this firmware's codegen"
#endif
_Static_assert(TCM_ZERO_AT_POWERUP == 0 || TCM_ZERO_AT_POWERUP == 1, "TCM_ZERO_AT_POWERUP is 0 or 1");

const tcm_model_t *model_binding_model(void)
{
    return &tcm_model;
}

uint32_t model_binding_expected_crc(void)
{
    return (uint32_t)TCM_MODEL_CRC32;
}

const char *model_binding_hash(void)
{
    return TCM_MODEL_HASH;
}

uint32_t model_binding_period_ms(void)
{
    return (uint32_t)TCM_SAMPLE_PERIOD_MS;
}

int model_binding_zero_at_powerup(void)
{
    return TCM_ZERO_AT_POWERUP;
}
