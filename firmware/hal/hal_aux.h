/* Auxiliary analogue inputs (spindle speed), already scaled to the model's unit (rpm). */
#ifndef HAL_AUX_H
#define HAL_AUX_H

#include <stdbool.h>
#include <stdint.h>

/* Read aux input `index` into *value; false if the input does not exist or did not convert. */
bool hal_aux_read(uint8_t index, int32_t *value);

#endif
