#include "cmd.h"

#include <string.h>

void cmd_reader_init(cmd_reader_t *r)
{
    r->len = 0;
    r->too_long = false;
    r->binary = false;
}

static cmd_t error(const char *reason)
{
    cmd_t c = {CMD_ERROR, 0, reason, 0, 0, 0, {0}};
    return c;
}

bool cmd_reader_push(cmd_reader_t *r, uint8_t byte, cmd_t *out)
{
    if (byte == '\r' || byte == '\n') {
        bool had_content = r->len > 0u || r->too_long || r->binary;
        if (had_content) {
            /* Binary wins: it usually means a wrong baud rate, the likelier fault to report. */
            if (r->binary) {
                *out = error("BINARY");
            } else if (r->too_long) {
                *out = error("TOO_LONG");
            } else {
                *out = cmd_parse(r->buf, r->len);
            }
        }
        cmd_reader_init(r);
        return had_content;
    }
    if (byte < 0x20u || byte > 0x7Eu) {
        r->binary = true;
        return false;
    }
    if (r->len >= CMD_MAX_LEN) {
        r->too_long = true;
        return false;
    }
    r->buf[r->len++] = (char)byte;
    return false;
}

static bool equals(const char *line, uint8_t len, const char *word)
{
    size_t n = strlen(word);
    return len == n && memcmp(line, word, n) == 0;
}

/* n decimal fields separated by single spaces, each of 1 to 10 digits and below 2^32; field
 * `neg_field` (-1: none) may start with '-' and must fit int32_t (two's complement in out).
 * false for any other text. */
static bool parse_fields(const char *s, uint8_t len, uint32_t *out, uint8_t n, int neg_field)
{
    const char *end = s + len;
    for (int f = 0; f < n; f++) {
        const bool neg = f == neg_field && s < end && *s == '-';
        s += neg;
        const char *start = s;
        uint32_t v = 0u;
        bool over = false; /* v * 10 + d beyond 2^32 - 1: 32-bit arithmetic only */
        while (s < end && *s >= '0' && *s <= '9') {
            const uint32_t d = (uint32_t)(*s++ - '0');
            over |= v > (UINT32_MAX - d) / 10u;
            v = v * 10u + d;
        }
        if (s == start || s - start > 10 || over ||
            v > (f == neg_field ? (uint32_t)INT32_MAX + neg : UINT32_MAX)) {
            return false;
        }
        out[f] = neg ? 0u - v : v;
        if (s == end) {
            return f + 1 == n;
        }
        if (*s++ != ' ') {
            return false;
        }
    }
    return false; /* text after the n-th field */
}

static cmd_t parse_rate(const char *arg, uint8_t len)
{
    uint32_t n;
    if (len > 4u || !parse_fields(arg, len, &n, 1u, -1) || n < CMD_RATE_MIN ||
        n > CMD_RATE_MAX) { /* "3600" is the longest valid argument */
        return error("BAD_ARG");
    }
    cmd_t c = {CMD_RATE, n, 0, 0, 0, 0, {0}};
    return c;
}

static cmd_t parse_resume(const char *arg, uint8_t len)
{
    uint32_t n;
    if (len > 5u || !parse_fields(arg, len, &n, 1u, -1) || n > CMD_RESUME_MAX) {
        return error("BAD_ARG");
    }
    cmd_t c = {CMD_RESUME, n, 0, 0, 0, 0, {0}};
    return c;
}

static cmd_t parse_meas(const char *arg, uint8_t len)
{
    uint32_t v[3];
    if (!parse_fields(arg, len, v, 3u, 1)) {
        return error("BAD_ARG");
    }
    cmd_t c = {CMD_MEAS, v[0], 0, (int32_t)v[1], v[2], 0, {0}};
    return c;
}

static int hex_digit(char ch)
{
    if (ch >= '0' && ch <= '9') {
        return ch - '0';
    }
    if (ch >= 'A' && ch <= 'F') {
        return ch - 'A' + 10;
    }
    if (ch >= 'a' && ch <= 'f') {
        return ch - 'a' + 10;
    }
    return -1;
}

static cmd_t parse_load(const char *arg, uint8_t len)
{
    const char *space = memchr(arg, ' ', len);
    uint32_t off;
    if (space == NULL || space - arg > 5 || !parse_fields(arg, (uint8_t)(space - arg), &off, 1u, -1) ||
        off > 65535u) {
        return error("BAD_ARG");
    }
    const char *hex = space + 1;
    const uint8_t n_hex = (uint8_t)(len - (uint8_t)(hex - arg));
    if (n_hex == 0u || n_hex % 2u != 0u || n_hex > 2u * CMD_LOAD_MAX_BYTES) {
        return error("BAD_ARG");
    }
    cmd_t c = {CMD_LOAD, off, 0, 0, 0, (uint8_t)(n_hex / 2u), {0}};
    for (uint8_t i = 0; i < c.n_bytes; i++) {
        const int hi = hex_digit(hex[2u * i]), lo = hex_digit(hex[2u * i + 1u]);
        if (hi < 0 || lo < 0) {
            return error("BAD_ARG");
        }
        c.data[i] = (uint8_t)(hi * 16 + lo);
    }
    return c;
}

cmd_t cmd_parse(const char *line, uint8_t len)
{
    if (equals(line, len, "INFO")) {
        cmd_t c = {CMD_INFO, 0, 0, 0, 0, 0, {0}};
        return c;
    }
    if (equals(line, len, "STATUS")) {
        cmd_t c = {CMD_STATUS, 0, 0, 0, 0, 0, {0}};
        return c;
    }
    if (equals(line, len, "ZERO")) {
        cmd_t c = {CMD_ZERO, 0, 0, 0, 0, 0, {0}};
        return c;
    }
    if (equals(line, len, "RATE")) {
        return error("BAD_ARG");
    }
    if (len >= 5u && memcmp(line, "RATE ", 5) == 0) {
        return parse_rate(line + 5, (uint8_t)(len - 5u));
    }
    if (len >= 7u && memcmp(line, "RESUME ", 7) == 0) {
        return parse_resume(line + 7, (uint8_t)(len - 7u));
    }
    if (equals(line, len, "RESUME")) {
        return error("BAD_ARG");
    }
    if (equals(line, len, "MEAS")) {
        return error("BAD_ARG");
    }
    if (equals(line, len, "SNAP")) {
        cmd_t c = {CMD_SNAP, 0, 0, 0, 0, 0, {0}};
        return c;
    }
    if (equals(line, len, "LOAD")) {
        return error("BAD_ARG");
    }
    if (len >= 5u && memcmp(line, "LOAD ", 5) == 0) {
        return parse_load(line + 5, (uint8_t)(len - 5u));
    }
    if (len >= 5u && memcmp(line, "MEAS ", 5) == 0) {
        return parse_meas(line + 5, (uint8_t)(len - 5u));
    }
    return error("UNKNOWN");
}
