/* Builds one protocol line `$<TYPE>,<fields>*<CRC16>\r\n` (docs/protocol.md) in a fixed buffer.
 * Every put is bounds-checked: a line that would not fit is marked overflowed and
 * line_finish() refuses it, so a truncated line can never go out with a valid CRC. */
#ifndef LINE_H
#define LINE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* Sized for the longest INFO line: 6 axes and 8 channels with 32-character names (app.c
 * asserts the bound for the configured capacities). */
#define LINE_MAX 640
/* Longest name line_put_name writes (codegen's limit for sensor and axis names). */
#define LINE_NAME_MAX 32u
/* "*XXXX\r\n" */
#define LINE_TRAILER_LEN 7

typedef struct {
    char buf[LINE_MAX];
    uint16_t len;
    bool overflow;
} line_t;

/* Start a line of the given type ("C", "I", ...): writes "$TYPE". */
void line_begin(line_t *l, const char *type);
/* Field separator ','. */
void line_sep(line_t *l);
void line_put_char(line_t *l, char c);
void line_put_str(line_t *l, const char *s);
/* A name from the model: characters outside [A-Za-z0-9_.+-] become '_' so a name can never
 * break the line's syntax (',', ';', ':', '*', '$'); at most LINE_NAME_MAX characters. */
void line_put_name(line_t *l, const char *s);
void line_put_u32(line_t *l, uint32_t v);
void line_put_i32(line_t *l, int32_t v);
/* `digits` upper-case hex digits (1..8) of v. */
void line_put_hex(line_t *l, uint32_t v, unsigned digits);
/* Append "*CRC\r\n"; returns the total length, or 0 if the line overflowed. */
size_t line_finish(line_t *l);

#endif
