/* Commands from the CNC side (docs/protocol.md): assembles bytes into lines and parses them.
 * A line ends at CR or LF (CR LF is one end; empty lines are ignored). Lines longer than
 * CMD_MAX_LEN characters are discarded up to the next line end and answered TOO_LONG once;
 * lines with bytes outside printable ASCII are answered BINARY. */
#ifndef CMD_H
#define CMD_H

#include <stdbool.h>
#include <stdint.h>

#define CMD_MAX_LEN 64u
#define CMD_RATE_MIN 1u
#define CMD_RATE_MAX 3600u
#define CMD_RESUME_MAX 65535u /* RESUME <n>: sample periods the box was off (0..65535) */
/* LOAD <offset> <hex>: up to CMD_LOAD_MAX_BYTES bytes (2 hex digits each, either case) of a
 * state block the controller kept (SNAP), written at byte <offset> (decimal, <= 65535) of the
 * retained memory; anything else is BAD_ARG. */
#define CMD_LOAD_MAX_BYTES 24u
/* MEAS <axis> <nm> <seq>: three decimal fields separated by one space each (at most 10
 * digits each), axis and seq unsigned 32-bit, nm signed 32-bit ('-' for negative, no '+');
 * anything else is BAD_ARG. */

typedef enum {
    CMD_INFO,
    CMD_STATUS,
    CMD_RATE,
    CMD_ZERO,
    CMD_MEAS,
    CMD_RESUME,
    CMD_SNAP,
    CMD_LOAD,
    CMD_ERROR,
} cmd_kind_t;

typedef struct {
    cmd_kind_t kind;
    uint32_t arg;       /* RATE: n; MEAS: the axis (any uint32: the application judges it);
                         * RESUME: the sample periods the box was off; LOAD: the offset */
    const char *reason; /* ERROR: "UNKNOWN", "TOO_LONG", "BINARY" or "BAD_ARG" */
    int32_t nm;         /* MEAS: the reading, nm (int32) */
    uint32_t seq;       /* MEAS: the sample it refers to (uint32) */
    uint8_t n_bytes;    /* LOAD: bytes in data */
    uint8_t data[CMD_LOAD_MAX_BYTES];
} cmd_t;

typedef struct {
    char buf[CMD_MAX_LEN];
    uint8_t len;
    bool too_long;
    bool binary;
} cmd_reader_t;

void cmd_reader_init(cmd_reader_t *r);

/* Feed one received byte; true when it completed a line, with the command in *out. */
bool cmd_reader_push(cmd_reader_t *r, uint8_t byte, cmd_t *out);

/* Parse one complete line (without its line end) of printable ASCII. */
cmd_t cmd_parse(const char *line, uint8_t len);

#endif
