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
    cmd_t c = {CMD_ERROR, 0, reason};
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

static cmd_t parse_rate(const char *arg, uint8_t len)
{
    if (len == 0u || len > 4u) { /* "3600" is the longest valid argument */
        return error("BAD_ARG");
    }
    uint32_t n = 0;
    for (uint8_t i = 0; i < len; i++) {
        if (arg[i] < '0' || arg[i] > '9') {
            return error("BAD_ARG");
        }
        n = n * 10u + (uint32_t)(arg[i] - '0');
    }
    if (n < CMD_RATE_MIN || n > CMD_RATE_MAX) {
        return error("BAD_ARG");
    }
    cmd_t c = {CMD_RATE, n, 0};
    return c;
}

cmd_t cmd_parse(const char *line, uint8_t len)
{
    if (equals(line, len, "INFO")) {
        cmd_t c = {CMD_INFO, 0, 0};
        return c;
    }
    if (equals(line, len, "STATUS")) {
        cmd_t c = {CMD_STATUS, 0, 0};
        return c;
    }
    if (equals(line, len, "ZERO")) {
        cmd_t c = {CMD_ZERO, 0, 0};
        return c;
    }
    if (equals(line, len, "RATE")) {
        return error("BAD_ARG");
    }
    if (len >= 5u && memcmp(line, "RATE ", 5) == 0) {
        return parse_rate(line + 5, (uint8_t)(len - 5u));
    }
    return error("UNKNOWN");
}
