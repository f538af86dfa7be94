/* The box application (docs/firmware.md describes the behaviour, docs/protocol.md the lines). */
#include "app.h"

#include <stdbool.h>
#include <stddef.h>
#include <string.h>

#include "axis_output.h"
#include "box_config.h"
#include "channel_guard.h"
#include "cmd.h"
#include "estimator.h"
#include "hal_aux.h"
#include "hal_board.h"
#include "hal_retain.h"
#include "hal_time.h"
#include "hal_uart.h"
#include "hal_watchdog.h"
#include "line.h"
#include "max31856.h"
#include "model_binding.h"
#include "model_eval.h"
#include "status.h"

/* Longest sample line: "$C," seq "," status "," n_axes ("," corr)* "," n_ch ("," code)* + trailer.
 * A 19-bit code has at most 7 characters, a correction (clamped) at most 11. */
#define SAMPLE_LINE_MAX                                                                      \
    (3 + 10 + 1 + 4 + 1 + 1 + BOX_MAX_AXES * (1 + 11) + 1 + 2 + BOX_MAX_CHANNELS * (1 + 7) + \
     LINE_TRAILER_LEN)
_Static_assert(SAMPLE_LINE_MAX <= LINE_MAX, "a full sample line must fit the line buffer");
/* Longest INFO line: "$I," fw "," hash ",BAD," period "," axis names ";" ... "," then
 * "ch:sensor:T;" per channel, names at most LINE_NAME_MAX characters. */
#define INFO_LINE_MAX                                                                        \
    (3 + (sizeof BOX_FW_VERSION - 1) + 1 + LINE_NAME_MAX + 5 + 10 + 1 +                     \
     BOX_MAX_AXES * (LINE_NAME_MAX + 1) + 1 + BOX_MAX_CHANNELS * (2 + 1 + LINE_NAME_MAX + 3) + \
     LINE_TRAILER_LEN)
_Static_assert(INFO_LINE_MAX <= LINE_MAX, "the longest INFO line must fit the line buffer");
_Static_assert(BOX_MAX_CHANNELS <= 32 && BOX_MAX_AXES <= 32, "masks are uint32_t");
/* Longest STATUS line: the fixed fields, a fault word per channel, then per axis the
 * estimator "bias:innovation:refusals:reopens" (7 + 11 + 5 + 5 characters and separators). */
#define STATUS_LINE_MAX                                                                      \
    (3 + 4 + 1 + 10 + 1 + 10 + 1 + BOX_MAX_CHANNELS * 5 + 1 + 10 + 1 +                       \
     BOX_MAX_AXES * (7 + 1 + 11 + 1 + 5 + 1 + 5 + 1) + LINE_TRAILER_LEN)
_Static_assert(STATUS_LINE_MAX <= LINE_MAX, "the longest STATUS line must fit the line buffer");

/* ---- MEAS: the samples the box remembers (docs/service.md, "On the box") ------------------
 * A reading names the sample it refers to. The box keeps, per axis, the referenced model
 * value (before the bias) of the latest BOX_MEAS_SAMPLES samples and whether a reading of
 * that sample may be used (the axis tracked its model, with a complete reference). */
#define MEAS_OK 0u
#define MEAS_NO_REF 1u  /* no reference, or the reference was still being averaged */
#define MEAS_HOLDING 2u /* the axis held (an input faulted) or walked back */

typedef struct {
    uint32_t newest_seq; /* seq of the newest entry (valid when count > 0) */
    uint8_t count;       /* entries held: consecutive samples up to newest_seq */
    uint8_t head;        /* index of the newest entry */
    int32_t model_nm[BOX_MEAS_SAMPLES][BOX_MAX_AXES];
    uint8_t flag[BOX_MEAS_SAMPLES][BOX_MAX_AXES]; /* MEAS_* */
} meas_ring_t;
_Static_assert(BOX_MEAS_SAMPLES >= 1 && BOX_MEAS_SAMPLES <= 255, "MEAS samples: 1..255");

#define DEFAULT_PERIOD_MS 1000u

typedef struct {
    const tcm_model_t *model;
    bool model_ok;
    uint32_t n_channels; /* bounded copies of the table sizes, safe even for a bad table */
    uint32_t n_aux;
    uint32_t n_axes;
    uint32_t period_ms;

    uint16_t sticky;  /* MODEL_BAD, WDT_RESET: hold for the whole power cycle */
    uint16_t status;  /* status word of the latest sample */
    uint32_t seq;     /* seq of the next sample */
    bool sampled;     /* a sample has been taken since power-up */
    /* A cold power-up found this model's retained block intact (a battery on VBAT kept it
     * through the power cut): it is left untouched until RESUME <n> continues it or a ZERO
     * starts afresh (docs/firmware.md, "Never worse than no compensation"). */
    bool resumable;
    bool skipping; /* RESUME: running the samples the box was off for (no chip, no line) */
    uint32_t next_sample_ms;
    uint32_t rate;
    uint32_t rate_left; /* samples until the next emitted line */

    bool zero_pending; /* ZERO received: the next sample starts a reference */
    bool referenced;   /* a ZERO reference is in force (REFERENCED) */
    uint32_t zero_seq; /* seq of the first sample of that reference */
    bool needs_ref;    /* TCM_ZERO_AT_POWERUP: no correction without a reference (NO_REF) */
    /* A start-referenced model is judged BEYOND on each channel's change since the reference
     * (its first plausible reading after the ZERO), not on the absolute reading. */
    int32_t ref_code[BOX_MAX_CHANNELS];
    uint32_t ref_set; /* bit ch: ref_code[ch] taken for the reference in force */
    bool zero_blocked; /* an axis held (input fault) or walked (SLEW) at the latest sample:
                        * its output is not the model's, so a datum taken now is not the
                        * healthy box's: ZERO is refused */

    int32_t codes[BOX_MAX_CHANNELS];       /* as read (sent on the line) */
    int32_t model_codes[BOX_MAX_CHANNELS]; /* what the model gets (guarded) */
    uint16_t ch_fault[BOX_MAX_CHANNELS];
    uint16_t still[BOX_MAX_CHANNELS]; /* valid readings in a row with one code (0: none) */
    channel_guard_t guards[BOX_MAX_CHANNELS];
    int32_t aux[BOX_MAX_AUX];
    int32_t computed_nm[BOX_MAX_AXES];
    axis_output_t axes[BOX_MAX_AXES];
    axis_output_cfg_t out_cfg[BOX_MAX_AXES];

    meas_ring_t ring; /* not retained: after a warm reset MEAS names a new sample (SEQ) */

    cmd_reader_t reader;
    line_t line;
} app_t;

static app_t app;

/* ---- retained state (hal_retain.h) -------------------------------------------------------
 * Everything that makes the next sample line what it would have been without a reset: the
 * sequence, the reference, the filters, the guards and the output stage. Written after every
 * sample; trusted at boot only after a warm reset, for the same model, with a valid CRC. */
/* "TCMF": the layout with the estimator's re-opening streak ("TCME", the layout before it, is
 * refused: another magic, another size; such a box boots cold) */
#define RETAIN_MAGIC UINT32_C(0x54434d46)

typedef struct {
    uint32_t magic;
    uint32_t size;
    uint32_t model_crc;
    uint32_t seq;
    uint32_t rate;
    uint32_t rate_left;
    uint32_t zero_seq;
    uint8_t referenced;
    uint8_t zero_pending;
    uint8_t sampled;
    int32_t ref_code[BOX_MAX_CHANNELS];
    uint32_t ref_set;
    tcm_state_t tcm;
    channel_guard_t guards[BOX_MAX_CHANNELS];
    axis_output_t axes[BOX_MAX_AXES];
    int32_t codes[BOX_MAX_CHANNELS]; /* the latest readings: the stuck check compares with them */
    uint16_t still[BOX_MAX_CHANNELS];
    /* The in-service estimator lives here and nowhere else (one copy in RAM: the block is
     * what the box keeps anyway, written after every sample and every MEAS). */
    est_state_t est[BOX_MAX_AXES];
    uint16_t est_refusals[BOX_MAX_AXES]; /* readings the gate refused since the last accepted */
    uint32_t est_seen; /* bit a: axis a had a reading since its last reset (last innovation) */
    uint32_t crc; /* CRC-32 of every byte before it */
} retained_t;

static retained_t snap;
static est_state_t *const est = snap.est;
/* The filters live in the retained block too (one copy in RAM: 520 B for 8 channels). */
static tcm_state_t *const tcm = &snap.tcm;

static uint32_t crc32_bytes(const uint8_t *p, size_t n)
{
    uint32_t crc = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; i++) {
        crc ^= p[i];
        for (int b = 0; b < 8; b++) {
            crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
        }
    }
    return ~crc;
}

static uint32_t snap_crc(void)
{
    return crc32_bytes((const uint8_t *)&snap, offsetof(retained_t, crc));
}

/* The block as of now: the application's fields copied in, the CRC over it. */
static void snap_fill(void)
{
    snap.magic = RETAIN_MAGIC;
    snap.size = (uint32_t)sizeof snap;
    snap.model_crc = model_binding_expected_crc();
    snap.seq = app.seq;
    snap.rate = app.rate;
    snap.rate_left = app.rate_left;
    snap.zero_seq = app.zero_seq;
    snap.referenced = app.referenced;
    snap.zero_pending = app.zero_pending;
    snap.sampled = app.sampled;
    snap.ref_set = app.ref_set;
    for (uint32_t ch = 0; ch < BOX_MAX_CHANNELS; ch++) {
        snap.ref_code[ch] = app.ref_code[ch];
        snap.guards[ch] = app.guards[ch];
        snap.codes[ch] = app.codes[ch];
        snap.still[ch] = app.still[ch];
    }
    for (uint32_t a = 0; a < BOX_MAX_AXES; a++) {
        snap.axes[a] = app.axes[a];
    }
    snap.crc = snap_crc();
}

static void retain_save(void)
{
    if (!app.model_ok || app.resumable || app.skipping || hal_retain_size() < sizeof snap) {
        return;
    }
    snap_fill();
    hal_retain_write(0u, &snap, sizeof snap);
}

/* Continue from the block in snap (its filters and estimates are used in place). */
static void retain_apply(void)
{
    app.seq = snap.seq;
    app.rate = snap.rate;
    app.rate_left = snap.rate_left;
    app.zero_seq = snap.zero_seq;
    app.referenced = snap.referenced != 0u;
    app.zero_pending = snap.zero_pending != 0u;
    app.sampled = snap.sampled != 0u;
    app.ref_set = snap.ref_set;
    for (uint32_t ch = 0; ch < BOX_MAX_CHANNELS; ch++) {
        app.ref_code[ch] = snap.ref_code[ch];
        app.guards[ch] = snap.guards[ch];
        app.codes[ch] = snap.codes[ch];
        app.still[ch] = snap.still[ch];
    }
    for (uint32_t a = 0; a < BOX_MAX_AXES; a++) {
        app.axes[a] = snap.axes[a];
    }
}

/* The retained block read into snap: this model's and intact. */
static bool retained_valid(void)
{
    if (!app.model_ok || hal_retain_size() < sizeof snap) {
        return false;
    }
    hal_retain_read(0u, &snap, sizeof snap);
    return snap.magic == RETAIN_MAGIC && snap.size == (uint32_t)sizeof snap &&
           snap.model_crc == model_binding_expected_crc() && snap.crc == snap_crc() &&
           snap.rate >= 1u && snap.rate <= 3600u && snap.rate_left >= 1u &&
           snap.rate_left <= snap.rate;
}

/* A block kept for RESUME (found by a cold power-up, or written by LOAD) is marked in the word
 * after it. A watchdog reset before RESUME or ZERO must not continue that block as if the box
 * had never been off (it would skip the periods off and the samples since the power-up): with
 * the mark the box boots as it did after the power cut, and the block waits for RESUME. */
#define HELD_MAGIC UINT32_C(0x48454c44) /* "HELD" */

static void set_resumable(bool resumable)
{
    app.resumable = resumable;
    if (hal_retain_size() >= sizeof snap + sizeof(uint32_t)) {
        const uint32_t word = resumable ? HELD_MAGIC : 0u;
        hal_retain_write(sizeof snap, &word, sizeof word);
    }
}

static bool marked_held(void)
{
    uint32_t word = 0u;
    if (hal_retain_size() >= sizeof snap + sizeof(uint32_t)) {
        hal_retain_read(sizeof snap, &word, sizeof word);
    }
    return word == HELD_MAGIC;
}

/* After a warm reset: resume from the retained state if it is this model's and intact, and not
 * a block held for RESUME. After a cold power-up an intact block is kept for RESUME
 * (resumable) and the box starts cold. */
static bool retain_restore(void)
{
    if (!retained_valid()) {
        return false;
    }
    if (!hal_reset_was_warm() || marked_held()) {
        set_resumable(app.needs_ref); /* only a referenced state is worth continuing */
        return false;
    }
    retain_apply();
    return true;
}
/* Beyond what training supports (docs/firmware.md, "Extrapolation"): the training window
 * widened by BOX_BEYOND_SPAN_PERCENT of its span, at least BOX_BEYOND_MIN_CODES. A
 * start-referenced model judges the change since its reference instead: a warmer day shifts
 * every reading but not the change, and the model only uses the change; a change larger than
 * the whole trained span plus that margin is beyond it. Before a reference: nothing to judge
 * (every axis holds, NO_REF). */
static bool beyond_training(uint32_t ch, const tcm_channel_t *c, int32_t code)
{
    int64_t span = (int64_t)c->window_hi_code - c->window_lo_code;
    int64_t margin = span * BOX_BEYOND_SPAN_PERCENT / 100;
    if (margin < BOX_BEYOND_MIN_CODES) {
        margin = BOX_BEYOND_MIN_CODES;
    }
    if (!app.needs_ref) {
        return code < (int64_t)c->window_lo_code - margin ||
               code > (int64_t)c->window_hi_code + margin;
    }
    if (!app.referenced) {
        return false;
    }
    const uint32_t bit = (uint32_t)1u << ch;
    if ((app.ref_set & bit) == 0u) {
        app.ref_code[ch] = code; /* the first plausible reading of this reference */
        app.ref_set |= bit;
    }
    int64_t change = (int64_t)code - app.ref_code[ch];
    return change < -(span + margin) || change > span + margin;
}

/* The estimator parameters of axis a; NULL: no such axis, or no service block (MEAS OFF). */
static const tcm_service_t *service_of(uint32_t a)
{
    return a < app.n_axes && app.model->axes[a].service.on ? &app.model->axes[a].service
                                                            : NULL;
}

static void est_reset_all(void)
{
    /* bias 0, P 0, no innovation, no refusals: est, est_refusals and est_seen in one run */
    memset(snap.est, 0, offsetof(retained_t, crc) - offsetof(retained_t, est));
    for (uint32_t a = 0; a < app.n_axes; a++) {
        const tcm_service_t *sv = &app.model->axes[a].service;
        if (sv->p0_pmax) {
            est[a].p_q8 = sv->pmax_q8; /* no start reference: P starts at pmax */
        }
    }
}

static int32_t sat_i32(int64_t v)
{
    return v > INT32_MAX ? INT32_MAX : (v < INT32_MIN ? INT32_MIN : (int32_t)v);
}

/* Stuck: a valid reading with the same code as the channel's previous reading extends the
 * run, any other starts one; a reading that is not valid (chip fault, no answer, out of
 * range) ends it (still 0). The channel is a fault while the run is max_still_samples or
 * longer (docs/firmware.md, "Stuck channel"); 0 in the model: no check. */
static bool still_stuck(uint32_t ch, const tcm_channel_t *c, int32_t code)
{
    uint16_t n = app.still[ch];
    app.still[ch] = (n > 0u && code == app.codes[ch]) ? (uint16_t)(n < UINT16_MAX ? n + 1u : n)
                                                      : 1u;
    return app.model_ok && c->max_still_samples > 0u && app.still[ch] >= c->max_still_samples;
}

static uint32_t min_u32(uint32_t a, uint32_t b)
{
    return a < b ? a : b;
}

static void send_line(void)
{
    size_t n = line_finish(&app.line);
    if (n > 0u) {
        hal_uart_write((const uint8_t *)app.line.buf, n);
    }
}

static void send_error(const char *reason)
{
    line_begin(&app.line, "E");
    line_sep(&app.line);
    line_put_str(&app.line, reason);
    send_line();
}

static bool model_fits(const tcm_model_t *m)
{
    return m->n_channels <= BOX_MAX_CHANNELS && m->n_aux <= BOX_MAX_AUX &&
           m->n_axes <= BOX_MAX_AXES && m->n_states <= TCM_MAX_STATES &&
           (m->n_channels == 0u || m->channels != NULL) && (m->n_aux == 0u || m->aux != NULL) &&
           (m->n_axes == 0u || (m->axes != NULL && m->terms != NULL));
}

void app_init(void)
{
    hal_board_init();

    app = (app_t){0};
    app.model = model_binding_model();
    app.sticky = hal_reset_was_watchdog() ? STATUS_WDT_RESET : 0u;
    app.model_ok = model_fits(app.model) &&
                   tcm_model_crc32(app.model) == model_binding_expected_crc();
    if (!app.model_ok) {
        app.sticky |= STATUS_MODEL_BAD;
    }
    /* Keep sampling and reporting temperatures with a bad model, within safe bounds. */
    app.n_channels = min_u32(app.model->channels ? app.model->n_channels : 0u, BOX_MAX_CHANNELS);
    app.n_aux = min_u32(app.model->aux ? app.model->n_aux : 0u, BOX_MAX_AUX);
    app.n_axes = app.model_ok ? app.model->n_axes : 0u;
    app.period_ms = model_binding_period_ms();
    if (app.period_ms == 0u) {
        app.period_ms = DEFAULT_PERIOD_MS;
    }

    for (uint32_t ch = 0; ch < app.n_channels; ch++) {
        (void)max31856_configure((uint8_t)ch, app.model->channels[ch].tc_type);
    }
    for (uint32_t ch = 0; ch < BOX_MAX_CHANNELS; ch++) {
        channel_guard_init(&app.guards[ch]);
    }
    const int32_t walk_step = axis_output_step_nm(BOX_SLEW_NM_PER_S, app.period_ms);
    for (uint32_t a = 0; a < BOX_MAX_AXES; a++) {
        axis_output_init(&app.axes[a]);
        axis_output_cfg_t *cfg = &app.out_cfg[a];
        cfg->max_abs_nm = BOX_MAX_CORRECTION_NM;
        cfg->step_nm = walk_step;
        /* The model's per-axis limit (CRC-checked); a table that claims less than 1 nm
         * would freeze the output, so it is taken as 1 nm. */
        int32_t track = a < app.n_axes ? app.model->axes[a].max_step_nm : walk_step;
        cfg->track_step_nm = track < 1 ? 1 : track;
        cfg->zero_samples = BOX_ZERO_SAMPLES;
        cfg->cold_start_slew = BOX_COLD_START_SLEW != 0;
    }
    /* A start-referenced model corrects the change since a reference: after a cold power-up
     * there is none until the CNC side sends ZERO (NO_REF, every axis holds). */
    app.needs_ref = model_binding_zero_at_powerup() != 0;

    app.rate = 1u;
    app.rate_left = 1u;
    bool resumed = retain_restore();
    if (!resumed) {
        tcm_state_init(tcm); /* a failed restore may have left anything in the block */
        est_reset_all();
    }
    app.status = app.sticky | (app.n_axes > 0u && !resumed ? STATUS_NO_DATA : 0u) |
                 (app.needs_ref && !app.referenced ? STATUS_NO_REF : 0u);
    cmd_reader_init(&app.reader);
    app.next_sample_ms = hal_millis() + app.period_ms;
    hal_watchdog_start(BOX_WATCHDOG_MS);
}

uint32_t app_next_sample_ms(void)
{
    return app.next_sample_ms;
}

/* ---- sampling -------------------------------------------------------------------------- */

static uint16_t sample_channels(uint32_t *valid_mask)
{
    uint16_t st = 0;
    *valid_mask = 0;
    for (uint32_t ch = 0; ch < app.n_channels; ch++) {
        const tcm_channel_t *c = &app.model->channels[ch];
        max31856_reading_t r = {0, MAX31856_SR_OPEN, true}; /* RESUME: the box was off */
        uint16_t fault = 0;
        if (!app.skipping && !max31856_read((uint8_t)ch, c->tc_type, &r)) {
            fault |= CHFAULT_NO_RESPONSE;
            st |= STATUS_TC_FAULT;
        } else if (r.sr != 0u) {
            fault |= r.sr;
            st |= (r.sr & MAX31856_SR_OPEN) ? STATUS_OPEN : 0u;
            st |= (r.sr & (uint8_t)~MAX31856_SR_OPEN) ? STATUS_TC_FAULT : 0u;
        } else if (r.code < c->min_code || r.code > c->max_code) {
            fault |= CHFAULT_RANGE;
            st |= STATUS_RANGE;
        } else if (still_stuck(ch, c, r.code)) {
            /* a frozen converter: a channel fault (its axes hold); the guard counts the
             * sample as lost, so the first reading that moves again is judged (below) */
            fault |= CHFAULT_STUCK;
        } else {
            int32_t use = r.code;
            guard_result_t g = GUARD_OK;
            if (app.model_ok) {
                g = channel_guard_check(&app.guards[ch], r.code, c->max_step_code,
                                        (uint8_t)BOX_IMPLAUSIBLE_FAULT_SAMPLES, &use);
            }
            if (g != GUARD_OK) {
                fault |= CHFAULT_IMPLAUSIBLE;
                st |= STATUS_IMPLAUSIBLE;
            }
            if (g != GUARD_FAULT && app.model_ok && beyond_training(ch, c, use)) {
                fault |= CHFAULT_BEYOND; /* runaway, stuck far off, or a day far outside */
                st |= STATUS_BEYOND;
            } else if (g != GUARD_FAULT) {
                *valid_mask |= (uint32_t)1u << ch;
                if (use < c->window_lo_code || use > c->window_hi_code) {
                    st |= STATUS_EXTRAP; /* still corrected: advice, not a fault */
                }
            }
            app.model_codes[ch] = use;
        }
        if (fault & (uint16_t)~(CHFAULT_IMPLAUSIBLE | CHFAULT_BEYOND | CHFAULT_STUCK)) {
            app.still[ch] = 0u; /* not a valid reading: the run of one code is broken */
        }
        if (fault & (uint16_t)~(CHFAULT_IMPLAUSIBLE | CHFAULT_BEYOND)) {
            channel_guard_lost(&app.guards[ch]); /* accepted afresh when it comes back */
            app.model_codes[ch] = r.code;
        }
        app.codes[ch] = r.code;
        app.ch_fault[ch] = fault;
    }
    return st;
}

static uint16_t sample_aux(void)
{
    uint16_t st = 0;
    for (uint32_t k = 0; k < app.n_aux; k++) {
        const tcm_aux_t *x = &app.model->aux[k];
        int32_t v;
        if (app.skipping || !hal_aux_read((uint8_t)k, &v)) {
            /* The runtime judges aux validity by range: hand it a value outside the range. */
            v = x->min > INT32_MIN ? x->min - 1 : (x->max < INT32_MAX ? x->max + 1 : 0);
            st |= STATUS_AUX_FAULT;
        } else if (v < x->min || v > x->max) {
            st |= STATUS_AUX_FAULT;
        }
        app.aux[k] = v;
    }
    return st;
}

static void send_sample_line(uint32_t seq)
{
    line_t *l = &app.line;
    line_begin(l, "C");
    line_sep(l);
    line_put_u32(l, seq);
    line_sep(l);
    line_put_hex(l, app.status, 4);
    line_sep(l);
    line_put_u32(l, app.n_axes);
    for (uint32_t a = 0; a < app.n_axes; a++) {
        line_sep(l);
        line_put_i32(l, app.axes[a].out_nm);
    }
    line_sep(l);
    line_put_u32(l, app.n_channels);
    for (uint32_t ch = 0; ch < app.n_channels; ch++) {
        line_sep(l);
        line_put_i32(l, app.codes[ch]);
    }
    send_line();
}

static void take_sample(void)
{
    uint32_t valid_mask;
    uint32_t seq = app.seq++;
    uint16_t st = app.sticky;
    /* the estimators' P grows every sample after their reference sample (power-up, ZERO) */
    bool est_ticks = app.sampled;
    meas_ring_t *ring = &app.ring;
    if (ring->count > 0u && seq != ring->newest_seq + 1u) {
        ring->count = 0u; /* a stalled loop skipped samples: remember consecutive ones only */
    }
    if (app.zero_pending) {
        /* ZERO: this sample is the first of the new reference. */
        app.zero_pending = false;
        app.referenced = true;
        app.zero_seq = seq;
        app.ref_set = 0u; /* each channel's reference reading is taken afresh */
        /* The touch-off takes the machine as it is, the estimate included: the limiter
         * moves by the bias as it moves by the reference (no step), and the estimate starts
         * again from the new datum (docs/service.md, "ZERO"). */
        for (uint32_t a = 0; a < BOX_MAX_AXES; a++) {
            axis_output_t *ax = &app.axes[a];
            if (ax->has_output && est[a].bias_nm != 0) {
                int64_t moved = (int64_t)ax->out_nm - est[a].bias_nm;
                int32_t lim = app.out_cfg[a].max_abs_nm;
                if (moved > lim || moved < -(int64_t)lim) {
                    st |= STATUS_CLAMP;
                    moved = moved > 0 ? lim : -(int64_t)lim;
                }
                ax->out_nm = (int32_t)moved;
            }
            axis_output_zero(ax);
        }
        est_reset_all();
        est_ticks = false;
        ring->count = 0u; /* readings refer to the new datum */
    }
    if (app.referenced) {
        st |= STATUS_REFERENCED;
    }
    st |= sample_channels(&valid_mask);
    st |= sample_aux();
    app.zero_blocked = false;
    if (app.model_ok) {
        /* Called every period, also with every channel faulted, so the time term counts. */
        uint32_t ok = tcm_step(app.model, tcm, app.model_codes, valid_mask,
                               app.n_aux > 0u ? app.aux : NULL, app.computed_nm);
        bool no_ref = app.needs_ref && !app.referenced;
        if (no_ref) {
            st |= STATUS_NO_REF; /* the filters run; no axis moves until ZERO */
        }
        ring->head = (uint8_t)((ring->head + 1u) % BOX_MEAS_SAMPLES);
        ring->newest_seq = seq;
        ring->count = (uint8_t)(ring->count < BOX_MEAS_SAMPLES ? ring->count + 1u : ring->count);
        for (uint32_t a = 0; a < app.n_axes; a++) {
            bool valid = ((ok >> a) & 1u) != 0u;
            const tcm_service_t *svc = service_of(a);
            if (svc && est_ticks) {
                est_tick(&est[a], svc);
            }
            /* the estimate adds to the model's value before the output stage: clamp and step
             * limit apply to the sum (the output walks to a corrected value) */
            axis_output_t *ax = &app.axes[a];
            uint16_t f = axis_output_update(ax, &app.out_cfg[a], valid && !no_ref,
                                            sat_i32((int64_t)app.computed_nm[a] + est[a].bias_nm));
            if (!valid || (f & STATUS_SLEW) != 0u) {
                app.zero_blocked = true; /* held, or still walking back to the model */
            }
            st |= f;
            ring->model_nm[ring->head][a] = sat_i32((int64_t)app.computed_nm[a] - ax->ref_nm);
            ring->flag[ring->head][a] = (uint8_t)((no_ref || ax->zeroing) ? MEAS_NO_REF
                                                  : (!valid || ax->walking) ? MEAS_HOLDING
                                                                            : MEAS_OK);
        }
    }
    app.status = st;
    app.sampled = true;
    bool send = --app.rate_left == 0u && !app.skipping;
    if (app.rate_left == 0u) {
        app.rate_left = app.rate;
    }
    /* saved before the line goes out: a reset after a line was seen never repeats its sample
     * (at worst a reset in between loses that line: a gap in seq) */
    retain_save();
    if (send) {
        send_sample_line(seq);
    }
}

/* ---- commands -------------------------------------------------------------------------- */

static char tc_letter(uint8_t tc_type)
{
    return tc_type == TCM_TC_K ? 'K' : (tc_type == TCM_TC_J ? 'J' : '?');
}

static void send_info(void)
{
    line_t *l = &app.line;
    line_begin(l, "I");
    line_sep(l);
    line_put_str(l, BOX_FW_VERSION);
    line_sep(l);
    line_put_name(l, model_binding_hash());
    line_sep(l);
    line_put_str(l, app.model_ok ? "OK" : "BAD");
    line_sep(l);
    line_put_u32(l, app.period_ms);
    line_sep(l);
    for (uint32_t a = 0; a < app.n_axes; a++) {
        if (a > 0u) {
            line_put_char(l, ';');
        }
        line_put_name(l, app.model->axes[a].name ? app.model->axes[a].name : "");
    }
    line_sep(l);
    for (uint32_t ch = 0; ch < app.n_channels; ch++) {
        const tcm_channel_t *c = &app.model->channels[ch];
        if (ch > 0u) {
            line_put_char(l, ';');
        }
        line_put_u32(l, ch);
        line_put_char(l, ':');
        line_put_name(l, c->sensor ? c->sensor : "");
        line_put_char(l, ':');
        line_put_char(l, tc_letter(c->tc_type));
    }
    send_line();
}

/* sep, then v or '-' when it is not shown (the STATUS service field, the $M reply) */
static void put_opt_i32(char sep, bool shown, int32_t v)
{
    line_put_char(&app.line, sep);
    if (shown) {
        line_put_i32(&app.line, v);
    } else {
        line_put_char(&app.line, '-');
    }
}

static void send_status(void)
{
    line_t *l = &app.line;
    line_begin(l, "S");
    line_sep(l);
    line_put_hex(l, app.status, 4);
    line_sep(l);
    line_put_u32(l, app.sampled ? app.seq - 1u : 0u);
    line_sep(l);
    line_put_u32(l, hal_millis() / 1000u);
    line_sep(l);
    for (uint32_t ch = 0; ch < app.n_channels; ch++) {
        if (ch > 0u) {
            line_put_char(l, ';');
        }
        line_put_hex(l, app.ch_fault[ch], 4);
    }
    line_sep(l);
    if (app.referenced) {
        line_put_u32(l, app.zero_seq);
    } else {
        line_put_char(l, '-');
    }
    line_sep(l);
    for (uint32_t a = 0; a < app.n_axes; a++) {
        if (a > 0u) {
            line_put_char(l, ';');
        }
        if (!service_of(a)) {
            line_put_char(l, '-');
            continue;
        }
        line_put_i32(l, est[a].bias_nm);
        put_opt_i32(':', ((snap.est_seen >> a) & 1u) != 0u, est[a].last_innovation_nm);
        put_opt_i32(':', true, snap.est_refusals[a]);
        put_opt_i32(':', true, est[a].reopens);
    }
    send_line();
}

/* ---- MEAS <axis> <nm> <seq> (docs/protocol.md, docs/service.md) -------------------------
 * $M,<axis>,<seq>,<A|R>,<reason|->,<innovation_nm|->,<bias_nm|->,<p_nm2|->; the reasons are
 * checked in the order of contract.protocol.MEAS_REASONS. */
static void handle_meas(const cmd_t *c)
{
    const uint32_t a = c->arg;
    const tcm_service_t *svc = service_of(a);
    const meas_ring_t *ring = &app.ring;
    const char *reason; /* ",R,<reason>" refused, ",A,-" applied, ",A,REOPEN" re-opened */
    bool measured = false; /* the reading reached the estimator: its innovation is shown */
    uint32_t back = ring->newest_seq - c->seq; /* samples before the newest (wraps) */
    uint32_t at = (ring->head + BOX_MEAS_SAMPLES - back % BOX_MEAS_SAMPLES) % BOX_MEAS_SAMPLES;
    if (!svc) {
        reason = app.model_ok && a >= app.n_axes ? ",R,AXIS" : ",R,OFF";
    } else if ((app.needs_ref && !app.referenced) || app.zero_pending ||
               (back < ring->count && ring->flag[at][a] == MEAS_NO_REF)) {
        reason = ",R,NO_REF";
    } else if (back >= ring->count) {
        reason = ",R,SEQ";
    } else if (ring->flag[at][a] != MEAS_OK || ring->flag[ring->head][a] != MEAS_OK) {
        reason = ",R,HOLDING";
    } else {
        measured = true;
        uint32_t verdict = est_measure(&est[a], svc, c->nm, ring->model_nm[at][a]);
        snap.est_seen |= (uint32_t)1u << a;
        uint16_t *n = &snap.est_refusals[a];
        *n = verdict != EST_REFUSED ? 0u : (uint16_t)(*n + (*n < UINT16_MAX));
        reason = verdict == EST_REFUSED    ? ",R,GATE"
                 : verdict == EST_REOPENED ? ",A,REOPEN"
                                           : ",A,-";
        retain_save(); /* the estimate survives a warm reset before the next sample */
    }
    line_t *l = &app.line;
    line_begin(l, "M");
    line_sep(l);
    line_put_u32(l, a);
    line_sep(l);
    line_put_u32(l, c->seq);
    line_put_str(l, reason);
    /* without an estimator nothing is shown (est[0] is read, not sent); P < 2^30 nm^2 */
    const est_state_t *e = &est[svc ? a : 0u];
    put_opt_i32(',', measured, e->last_innovation_nm);
    put_opt_i32(',', svc != NULL, e->bias_nm);
    put_opt_i32(',', svc != NULL, (int32_t)EST_P_NM2(e));
    send_line();
}

static void send_ok(const char *what, uint32_t value)
{
    line_begin(&app.line, "OK");
    line_sep(&app.line);
    line_put_str(&app.line, what);
    line_sep(&app.line);
    line_put_u32(&app.line, value);
    send_line();
}

/* RESUME <n>: continue the retained state of the last power-up, as if the box had sampled
 * every channel as open for the n periods it was off and the ones since this power-up (the
 * filters catch up over the gap, the guards judge the next reading, the output holds and
 * walks back); its reference and sequence go on (docs/firmware.md, "Never worse than no
 * compensation"). */
static void handle_resume(uint32_t off)
{
    if (!app.resumable || !retained_valid()) {
        if (app.resumable) { /* the block changed since power-up: start afresh */
            set_resumable(false);
            tcm_state_init(tcm);
            est_reset_all();
        }
        send_error("NO_STATE");
        return;
    }
    const uint32_t since_boot = app.seq; /* samples this power-up has taken */
    retain_apply();
    set_resumable(false);
    app.sticky |= STATUS_WDT_RESET; /* reset, resumed from the retained state */
    app.skipping = true;
    for (uint32_t i = 0; i < off + since_boot; i++) {
        hal_watchdog_kick();
        take_sample();
    }
    app.skipping = false;
    send_ok("RESUME", app.sampled ? app.seq - 1u : 0u);
    retain_save();
}

/* SNAP: the block the box keeps in its retained memory, for the controller to keep too:
 * `$B,<offset>,<size>,<hex>` lines of SNAP_LINE_BYTES bytes, then `$OK,SNAP,<seq of the
 * latest sample>`. After a power cut that took the retained memory with it (no battery on
 * VBAT), LOAD puts the controller's copy back and RESUME continues it, as after a cut on a
 * battery (docs/firmware.md, "Never worse than no compensation"). The block is opaque to
 * the controller: the box checks its magic, model CRC and CRC-32 before it continues
 * anything. */
#define SNAP_LINE_BYTES 256u
static void handle_snap(void)
{
    if (!app.model_ok || app.resumable || app.skipping || !app.sampled) {
        send_error("NO_STATE"); /* nothing of its own worth keeping yet */
        return;
    }
    snap_fill();
    const uint8_t *bytes = (const uint8_t *)&snap;
    for (uint32_t off = 0; off < sizeof snap; off += SNAP_LINE_BYTES) {
        line_begin(&app.line, "B");
        line_sep(&app.line);
        line_put_u32(&app.line, off);
        line_sep(&app.line);
        line_put_u32(&app.line, (uint32_t)sizeof snap);
        line_sep(&app.line);
        for (uint32_t i = off; i < off + SNAP_LINE_BYTES && i < sizeof snap; i++) {
            line_put_hex(&app.line, bytes[i], 2u);
        }
        send_line();
        hal_watchdog_kick();
    }
    send_ok("SNAP", app.seq - 1u);
}

/* LOAD <offset> <hex>: a piece of a block SNAP gave, written into the retained memory. Only
 * while the box waits for a datum after a cold boot (its own state is worth nothing then);
 * from the first piece on the box stops writing its own block there, so RESUME continues the
 * uploaded one (or refuses it, NO_STATE, if the pieces do not make this model's intact
 * block). */
static void handle_load(const cmd_t *c)
{
    if (!app.needs_ref || app.referenced || app.zero_pending) {
        send_error("IN_USE"); /* a datum in force (or no reference at all): keep it */
        return;
    }
    if (hal_retain_size() < sizeof snap) {
        send_error("NO_RETAIN");
        return;
    }
    if (c->arg > sizeof snap || c->n_bytes > sizeof snap - c->arg) {
        send_error("BAD_ARG");
        return;
    }
    hal_retain_write(c->arg, c->data, c->n_bytes);
    set_resumable(true);
    send_ok("LOAD", c->arg + c->n_bytes);
}

static void handle_command(const cmd_t *c)
{
    switch (c->kind) {
    case CMD_INFO:
        send_info();
        break;
    case CMD_STATUS:
        send_status();
        break;
    case CMD_RATE:
        app.rate = c->arg;
        app.rate_left = 1u; /* the next sample goes out, then every n-th */
        send_ok("RATE", c->arg);
        break;
    case CMD_ZERO:
        if (app.zero_blocked) {
            /* A new datum taken while an axis holds or walks is not the
             * healthy box's: refuse, the CNC side asks again once the box tracks. */
            send_error("HOLDING");
            break;
        }
        app.zero_pending = true; /* the reference starts with the next sample */
        set_resumable(false); /* a new datum: the retained one is not continued */
        send_ok("ZERO", app.sampled ? app.seq - 1u : 0u);
        retain_save();
        break;
    case CMD_MEAS:
        handle_meas(c);
        break;
    case CMD_RESUME:
        handle_resume(c->arg);
        break;
    case CMD_SNAP:
        handle_snap();
        break;
    case CMD_LOAD:
        handle_load(c);
        break;
    case CMD_ERROR:
    default:
        send_error(c->reason ? c->reason : "UNKNOWN");
        break;
    }
}

/* ---- main loop ------------------------------------------------------------------------- */

void app_poll(void)
{
    hal_watchdog_kick();

    uint8_t rx[32];
    size_t n;
    while ((n = hal_uart_read(rx, sizeof rx)) > 0u) {
        for (size_t i = 0; i < n; i++) {
            cmd_t c;
            if (cmd_reader_push(&app.reader, rx[i], &c)) {
                handle_command(&c);
            }
        }
    }

    uint32_t late = hal_millis() - app.next_sample_ms;
    if ((int32_t)late >= 0) {
        /* Periods that passed without a sample (a stalled loop) show as a gap in seq. */
        uint32_t missed = late / app.period_ms;
        app.seq += missed;
        app.next_sample_ms += (missed + 1u) * app.period_ms;
        take_sample();
    }
}

int app_main(void)
{
    app_init();
    do {
        app_poll();
    } while (hal_wait_for_event(app.next_sample_ms));
    return 0;
}
