/* Plausibility guard of one thermocouple channel: a reading that changed faster than the
 * channel can physically change is not given to the model. Pure logic, no HAL.
 *
 * max_step is the largest plausible change per sample period, in codes (from the model: the
 * training runs' fastest change with a margin, docs/firmware.md). "since" counts the sample
 * periods since the last accepted reading ("last good"), lost samples included, so the
 * allowance max_step * since grows with the time a reading had to get there. Per reading that
 * passed the chip and range checks:
 *   no reference yet (power-up)
 *                      -> GUARD_OK, the reading becomes the reference
 *   |code - last_good| <= max_step * since, and not a runaway (below)
 *                      -> GUARD_OK, new last_good
 *   otherwise          -> implausible: GUARD_HELD (the model gets last_good instead) until
 *                         fault_after readings in a row were implausible, then GUARD_FAULT
 *   runaway            -> the reading is plausible step by step but the last
 *                         GUARD_RUNAWAY_SAMPLES accepted readings moved by more than
 *                         max_step * (GUARD_RUNAWAY_SAMPLES / 2 + 1) in all: faster, for
 *                         longer, than any change in training (the limit is 4 x the fastest
 *                         single step): GUARD_FAULT at once, last good goes back to the
 *                         reading before the run
 *   while GUARD_FAULT  -> the channel is a fault until fault_after consecutive readings each
 *                         changed plausibly from the one before, the newest is plausible
 *                         against last good (max_step * since) and the readings are no
 *                         runaway; that reading is accepted (GUARD_OK).
 * A channel that could not be read at all (chip fault, out of range) calls channel_guard_lost:
 * the guard keeps its last good reading and counts the sample, so the first reading after
 * the fault is judged like any other (a loose connector that comes back 100 degC off is held
 * and faulted, not trusted), while a sensor that comes back after an hour has an hour's
 * allowance. */
#ifndef CHANNEL_GUARD_H
#define CHANNEL_GUARD_H

#include <stdbool.h>
#include <stdint.h>

/* Readings of the runaway check (a constant of the contract: thermal_comp/codegen/fixed.py mirrors it). */
#define GUARD_RUNAWAY_SAMPLES 4u

typedef enum {
    GUARD_OK,    /* plausible: give the reading to the model */
    GUARD_HELD,  /* implausible: give last_good to the model for this sample */
    GUARD_FAULT, /* implausible too often, or a runaway: the channel is faulted */
} guard_result_t;

typedef struct {
    int32_t last_good; /* last accepted reading */
    int32_t prev;      /* while faulted: the previous reading */
    int32_t run[GUARD_RUNAWAY_SAMPLES]; /* the latest consecutive readings, oldest first */
    uint16_t since;    /* sample periods since last_good (saturating) */
    uint8_t run_n;     /* readings in run[] */
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
