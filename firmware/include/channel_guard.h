/* Plausibility guard of one thermocouple channel: a reading that changed faster than the
 * channel can physically change is not given to the model. Pure logic, no HAL.
 *
 * max_step is the largest plausible change per sample period, in codes (from the model: the
 * training runs' fastest change with a margin, docs/firmware.md). Per reading that passed the
 * chip and range checks:
 *   no reference yet (power-up, or after any other fault of the channel)
 *                      -> GUARD_OK, the reading becomes the reference ("last good")
 *   |code - last_good| <= max_step * (samples since last_good)
 *                      -> GUARD_OK, new last_good
 *   otherwise          -> implausible: GUARD_HELD (the model gets last_good instead) until
 *                         fault_after readings in a row were implausible, then GUARD_FAULT
 *   while GUARD_FAULT  -> the channel is a fault until fault_after consecutive readings each
 *                         changed plausibly from the one before; that reading is accepted as
 *                         the new reference (GUARD_OK) and the model takes it from there.
 * A channel that could not be read at all (chip fault, out of range) calls channel_guard_lost:
 * the guard forgets its reference, so a sensor that comes back after an hour is accepted as
 * after power-up (and the output walks back at the slew limit after its hold). */
#ifndef CHANNEL_GUARD_H
#define CHANNEL_GUARD_H

#include <stdbool.h>
#include <stdint.h>

typedef enum {
    GUARD_OK,    /* plausible: give the reading to the model */
    GUARD_HELD,  /* implausible: give last_good to the model for this sample */
    GUARD_FAULT, /* implausible too often: the channel is faulted */
} guard_result_t;

typedef struct {
    int32_t last_good; /* last accepted reading */
    int32_t prev;      /* while faulted: the previous reading */
    uint8_t bad_run;   /* implausible readings since last_good */
    uint8_t calm;      /* while faulted: plausible reading-to-reading changes in a row */
    bool has_ref;      /* last_good is set */
    bool faulted;
} channel_guard_t;

void channel_guard_init(channel_guard_t *g);

/* The channel had no usable reading this sample (chip fault, no answer, out of range). */
void channel_guard_lost(channel_guard_t *g);

/* Judge one reading. *model_code is what the model gets (the reading, or last_good when
 * GUARD_HELD; unchanged on GUARD_FAULT). max_step <= 0 disables the guard (GUARD_OK always);
 * fault_after >= 1. */
guard_result_t channel_guard_check(channel_guard_t *g, int32_t code, int32_t max_step,
                                   uint8_t fault_after, int32_t *model_code);

#endif
