#include "line.h"

#include "crc16.h"

static const char HEX_DIGITS[] = "0123456789ABCDEF";

void line_begin(line_t *l, const char *type)
{
    l->len = 0;
    l->overflow = false;
    line_put_char(l, '$');
    line_put_str(l, type);
}

void line_put_char(line_t *l, char c)
{
    /* Keep room for the trailer so line_finish() never fails for lack of space. */
    if (l->len >= LINE_MAX - LINE_TRAILER_LEN) {
        l->overflow = true;
        return;
    }
    l->buf[l->len++] = c;
}

void line_sep(line_t *l)
{
    line_put_char(l, ',');
}

void line_put_str(line_t *l, const char *s)
{
    while (*s != '\0') {
        line_put_char(l, *s++);
    }
}

static bool is_name_char(char c)
{
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
           c == '_' || c == '.' || c == '+' || c == '-';
}

void line_put_name(line_t *l, const char *s)
{
    for (unsigned n = 0; *s != '\0' && n < LINE_NAME_MAX; n++, s++) {
        line_put_char(l, is_name_char(*s) ? *s : '_');
    }
}

void line_put_u32(line_t *l, uint32_t v)
{
    char tmp[10];
    unsigned n = 0;
    do {
        tmp[n++] = (char)('0' + (v % 10u));
        v /= 10u;
    } while (v != 0u);
    while (n > 0u) {
        line_put_char(l, tmp[--n]);
    }
}

void line_put_i32(line_t *l, int32_t v)
{
    if (v < 0) {
        line_put_char(l, '-');
        /* Magnitude in unsigned arithmetic: correct for INT32_MIN too. */
        line_put_u32(l, 0u - (uint32_t)v);
    } else {
        line_put_u32(l, (uint32_t)v);
    }
}

void line_put_hex(line_t *l, uint32_t v, unsigned digits)
{
    if (digits < 1u || digits > 8u) {
        l->overflow = true;
        return;
    }
    for (unsigned i = digits; i > 0u; i--) {
        line_put_char(l, HEX_DIGITS[(v >> (4u * (i - 1u))) & 0xFu]);
    }
}

size_t line_finish(line_t *l)
{
    if (l->overflow || l->len + LINE_TRAILER_LEN > LINE_MAX) {
        return 0;
    }
    /* CRC over the bytes between '$' and '*' exclusive. */
    uint16_t crc = crc16_update(CRC16_INIT, (const uint8_t *)l->buf + 1, (size_t)l->len - 1u);
    l->buf[l->len++] = '*';
    for (unsigned i = 4; i > 0u; i--) {
        l->buf[l->len++] = HEX_DIGITS[(crc >> (4u * (i - 1u))) & 0xFu];
    }
    l->buf[l->len++] = '\r';
    l->buf[l->len++] = '\n';
    return l->len;
}
