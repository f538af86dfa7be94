/* The native board (docs/native-board.md): virtual time driven by a feed on stdin, simulated
 * MAX31856 chips, a pseudo-terminal UART. Everything above hal/ is the real firmware. */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <setjmp.h>
#include <signal.h>
#include <sys/time.h>
#include <limits.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "box_config.h"
#include "hal_aux.h"
#include "hal_board.h"
#include "hal_time.h"
#include "hal_watchdog.h"
#include "native_board.h"

/* ---- time, aux, watchdog, board -------------------------------------------------------- */

static uint32_t now_ms;
static int32_t aux0;
static bool reset_by_watchdog;
static int exit_status;

uint32_t hal_millis(void)
{
    return now_ms;
}

void native_advance_time_to(uint32_t ms)
{
    if ((int32_t)(ms - now_ms) > 0) {
        now_ms = ms;
    }
}

void native_set_aux0(int32_t value)
{
    aux0 = value;
}

bool hal_aux_read(uint8_t index, int32_t *value)
{
    if (index != 0u) {
        return false; /* the feed carries one aux input */
    }
    *value = aux0;
    return true;
}

void native_set_reset_cause_watchdog(bool wdt)
{
    reset_by_watchdog = wdt;
}

bool hal_reset_was_watchdog(void)
{
    return reset_by_watchdog;
}

bool hal_reset_was_warm(void)
{
    return reset_by_watchdog; /* the native board's resets are the watchdog's or power cuts */
}

/* ---- watchdog ----------------------------------------------------------------------------
 * The box's IWDG runs on its own clock while the loop wakes every millisecond and kicks it.
 * Here the loop sleeps in poll() between feed commands instead, so the simulated watchdog only
 * runs while the firmware is busy (from a kick until the next wait): a pass that burns
 * watchdog-timeout worth of CPU time (ITIMER_PROF, immune to a loaded host) is stuck. Expiry
 * "resets the chip": the firmware restarts from app_main with the reset cause set to the
 * watchdog and the tick back at 0, while the chips, the pty and the feed carry on. */

static sigjmp_buf reset_vector;
static uint32_t watchdog_timeout_ms;

static void watchdog_arm(uint32_t ms)
{
    struct itimerval t = {{0, 0}, {(time_t)(ms / 1000u), (suseconds_t)(ms % 1000u) * 1000}};
    (void)setitimer(ITIMER_PROF, &t, NULL);
}

static void watchdog_expired(int sig)
{
    (void)sig;
    siglongjmp(reset_vector, 1);
}

void hal_watchdog_start(uint32_t timeout_ms)
{
    watchdog_timeout_ms = timeout_ms;
    watchdog_arm(timeout_ms);
}

void hal_watchdog_kick(void)
{
    if (watchdog_timeout_ms != 0u) {
        watchdog_arm(watchdog_timeout_ms);
    }
}

void hal_board_init(void)
{
}

int native_exit_status(void)
{
    return exit_status;
}

/* ---- feed ------------------------------------------------------------------------------ */

#define FEED_BUF_SIZE 65536u

static char feed_buf[FEED_BUF_SIZE];
static size_t feed_len; /* bytes in feed_buf */
static size_t feed_pos; /* start of the first unprocessed byte */
static bool feed_eof;
static unsigned long feed_line_no;
static int chip_count = -1; /* fixed by the first S line */
static long hang_after_samples = -1; /* --hang-after-samples */
static long samples_fed;
static bool in_sample_line; /* the line being handled is an S line (sample samples_fed) */

/* Report a bad feed line and stop (exit 2). The message names the line and the sample it is
 * (S lines) or comes before (other lines), so a replay that dies can say where. */
__attribute__((format(printf, 1, 2))) static bool feed_error(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "thermal_box: feed line %lu (%ssample %ld): ", feed_line_no,
            in_sample_line ? "" : "before ", samples_fed);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
    exit_status = 2;
    return false;
}

/* Next complete line in the buffer (NUL-terminated in place), or NULL. At end of input a
 * final line without a newline counts as complete. */
static char *next_line(void)
{
    char *start = feed_buf + feed_pos;
    char *nl = memchr(start, '\n', feed_len - feed_pos);
    if (nl == NULL) {
        if (!feed_eof || feed_pos == feed_len) {
            return NULL;
        }
        if (feed_len == FEED_BUF_SIZE) {
            return NULL;
        }
        nl = feed_buf + feed_len;
        feed_len++; /* account for the terminator written below */
    }
    *nl = '\0';
    feed_pos = (size_t)(nl - feed_buf) + 1u;
    feed_line_no++;
    return start;
}

/* Read more feed bytes (stdin is readable). False on a line too long for the buffer. */
static bool fill_feed(void)
{
    if (feed_pos > 0u) {
        memmove(feed_buf, feed_buf + feed_pos, feed_len - feed_pos);
        feed_len -= feed_pos;
        feed_pos = 0;
    }
    if (feed_len == FEED_BUF_SIZE) {
        feed_line_no++;
        return feed_error("%s", "longer than 65536 bytes");
    }
    ssize_t n = read(STDIN_FILENO, feed_buf + feed_len, FEED_BUF_SIZE - feed_len);
    if (n > 0) {
        feed_len += (size_t)n;
    } else if (n == 0 || (errno != EINTR && errno != EAGAIN)) {
        feed_eof = true;
    }
    return true;
}

static bool parse_long(const char *tok, int base, long lo, long hi, long *out)
{
    if (tok == NULL || *tok == '\0') {
        return false;
    }
    char *end;
    errno = 0;
    long v = strtol(tok, &end, base);
    if (errno != 0 || *end != '\0' || v < lo || v > hi) {
        return false;
    }
    *out = v;
    return true;
}

static bool feed_sample(char *rest, uint32_t wake_at_ms)
{
    char *save;
    char *tok = strtok_r(rest, " \t\r", &save);
    long aux;
    if (!parse_long(tok, 10, INT32_MIN, INT32_MAX, &aux)) {
        return feed_error("S: aux value '%s' is not a 32-bit integer", tok ? tok : "");
    }
    int32_t codes[BOX_MAX_CHANNELS];
    int n = 0;
    while ((tok = strtok_r(NULL, " \t\r", &save)) != NULL) {
        long code;
        if (n >= (int)BOX_MAX_CHANNELS) {
            return feed_error("S: more than %d temperature codes", (int)BOX_MAX_CHANNELS);
        }
        if (!parse_long(tok, 10, MAX31856_SIM_CODE_MIN, MAX31856_SIM_CODE_MAX, &code)) {
            return feed_error("S: code '%s' is not an integer in -262144..262143 (19 bits)", tok);
        }
        codes[n++] = (int32_t)code;
    }
    if (n == 0) {
        return feed_error("%s", "S: no temperature codes");
    }
    if (chip_count < 0) {
        chip_count = n;
        native_set_chip_count((uint8_t)n);
    } else if (n != chip_count) {
        return feed_error("S: %d codes, the first S line had %d", n, chip_count);
    }
    for (int i = 0; i < n; i++) {
        max31856_sim_set_temperature(native_chip((uint8_t)i), codes[i]);
    }
    native_set_aux0((int32_t)aux);
    native_advance_time_to(wake_at_ms);
    if (samples_fed++ == hang_after_samples) {
        native_spi_hang_once();
    }
    return true;
}

static bool feed_fault(char *rest)
{
    char *save;
    char *ch_tok = strtok_r(rest, " \t\r", &save);
    char *sr_tok = strtok_r(NULL, " \t\r", &save);
    long ch, sr;
    if (!parse_long(ch_tok, 10, 0, BOX_MAX_CHANNELS - 1, &ch)) {
        return feed_error("F: channel '%s' is not a chip number (0..%d)", ch_tok ? ch_tok : "",
                          (int)BOX_MAX_CHANNELS - 1);
    }
    if (!parse_long(sr_tok, 16, 0, 0xFF, &sr)) {
        return feed_error("F: fault status '%s' is not a hex byte (e.g. 01)", sr_tok ? sr_tok : "");
    }
    if (strtok_r(NULL, " \t\r", &save) != NULL) {
        return feed_error("%s", "F: expected 'F <ch> <sr_hex>'");
    }
    max31856_sim_set_fault(native_chip((uint8_t)ch), (uint8_t)sr);
    return true;
}

/* Handle one feed line; false when the firmware should stop. */
static bool feed_command(char *line, uint32_t wake_at_ms)
{
    char *p = line;
    while (*p == ' ' || *p == '\t' || *p == '\r') {
        p++;
    }
    char cmd = *p;
    if (cmd == '\0') {
        return true; /* empty line */
    }
    char *rest = p + 1;
    if (*rest != '\0' && *rest != ' ' && *rest != '\t' && *rest != '\r') {
        return feed_error("unknown command '%s' (expected S, F or Q)", p);
    }
    switch (cmd) {
    case 'S': {
        in_sample_line = true;
        bool ok = feed_sample(rest, wake_at_ms);
        in_sample_line = false;
        return ok;
    }
    case 'F':
        return feed_fault(rest);
    case 'Q':
        return false;
    default:
        return feed_error("unknown command '%s' (expected S, F or Q)", p);
    }
}

bool hal_wait_for_event(uint32_t wake_at_ms)
{
    watchdog_arm(0); /* idle: the box would be kicking from its WFI loop */
    int uart = native_uart_fd();
    for (;;) {
        /* Bytes from the pty are answered first, at the current virtual time. */
        struct pollfd fds[2] = {{.fd = uart, .events = POLLIN}, {.fd = STDIN_FILENO, .events = POLLIN}};
        if (poll(fds, 1, 0) > 0 && (fds[0].revents & POLLIN)) {
            return true;
        }
        char *line = next_line();
        if (line != NULL) {
            return feed_command(line, wake_at_ms);
        }
        if (feed_eof) {
            return false;
        }
        int n = poll(fds, 2, -1);
        if (n < 0 && errno != EINTR) {
            fprintf(stderr, "thermal_box: poll: %s\n", strerror(errno));
            exit_status = 1;
            return false;
        }
        if (n > 0 && (fds[0].revents & POLLIN)) {
            return true;
        }
        if (n > 0 && (fds[1].revents & (POLLIN | POLLHUP | POLLERR))) {
            if (!fill_feed()) {
                return false;
            }
        }
    }
}

/* ---- main ------------------------------------------------------------------------------ */

static void usage(FILE *to)
{
    fputs("usage: thermal_box [--wdt-reset] [--retain FILE] [--hang-after-samples N] [--pty-fd N]\n"
          "Runs the box firmware on a pseudo-terminal (printed as 'PTY <path>') with a sample\n"
          "feed on stdin: 'S <aux0> <code0> ...', 'F <ch> <sr_hex>', 'Q'\n"
          "(docs/native-board.md).\n"
          "  --wdt-reset  start as if the last reset came from the watchdog\n"
          "  --retain FILE  keep the retained memory (backup SRAM) in FILE: a box started\n"
          "               again with the same FILE resumes where it was (a warm reset)\n"
          "  --hang-after-samples N  (test) the SPI bus locks up once, after N S lines: the\n"
          "               watchdog must reset the firmware\n"
          "  --pty-fd N   use the pseudo-terminal master inherited as file descriptor N as\n"
          "               the UART (the caller holds the slave) instead of creating one\n",
          to);
}

int main(int argc, char **argv)
{
    int pty_fd = -1;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--wdt-reset") == 0) {
            native_set_reset_cause_watchdog(true);
        } else if (strcmp(argv[i], "--retain") == 0 && i + 1 < argc) {
            if (!native_set_retain_file(argv[++i])) {
                fprintf(stderr, "thermal_box: --retain: cannot open '%s'\n", argv[i]);
                return 2;
            }
        } else if (strcmp(argv[i], "--hang-after-samples") == 0 && i + 1 < argc) {
            long n;
            if (!parse_long(argv[++i], 10, 0, LONG_MAX, &n)) {
                fprintf(stderr, "thermal_box: --hang-after-samples needs a count\n");
                return 2;
            }
            hang_after_samples = n;
        } else if (strcmp(argv[i], "--pty-fd") == 0 && i + 1 < argc) {
            long n;
            if (!parse_long(argv[++i], 10, 0, INT_MAX, &n)) {
                fprintf(stderr, "thermal_box: --pty-fd needs a file descriptor number\n");
                return 2;
            }
            pty_fd = (int)n;
        } else if (strcmp(argv[i], "--help") == 0 || strcmp(argv[i], "-h") == 0) {
            usage(stdout);
            return 0;
        } else {
            fprintf(stderr, "thermal_box: unknown option '%s'\n", argv[i]);
            usage(stderr);
            return 2;
        }
    }
    if (!native_uart_open(pty_fd)) {
        return 1;
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = watchdog_expired;
    sigemptyset(&sa.sa_mask);
    (void)sigaction(SIGPROF, &sa, NULL);
    if (sigsetjmp(reset_vector, 1) != 0) {
        fprintf(stderr, "thermal_box: watchdog reset (the loop stopped kicking)\n");
        native_set_reset_cause_watchdog(true);
        now_ms = 0;
        watchdog_timeout_ms = 0;
    }
    int rc = app_main();
    return rc != 0 ? rc : exit_status;
}
