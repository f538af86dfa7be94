/* UART HAL of the native board: a pseudo-terminal.
 *
 * Either the board creates the pty itself (the slave side is set raw and kept open by this
 * process, so the line discipline never echoes or translates bytes and the master never
 * reports a hang-up before the runner has opened the port), or the runner creates it and
 * passes the master down (--pty-fd N): then the runner holds the slave from the start and
 * never has to open a /dev/pts path that another process could have been given meanwhile.
 *
 * Writes never drop a byte: when the reader is behind, the write waits until the pty takes
 * more (like the box's transmit, which polls TXE); the HIL counts every line. */
#define _XOPEN_SOURCE 600
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include "hal_uart.h"
#include "native_board.h"

static int master_fd = -1;
static int slave_fd = -1;

static bool set_nonblocking(int fd)
{
    int flags = fcntl(fd, F_GETFL);
    if (flags < 0 || fcntl(fd, F_SETFL, flags | O_NONBLOCK) != 0) {
        fprintf(stderr, "thermal_box: fcntl: %s\n", strerror(errno));
        return false;
    }
    return true;
}

static bool create_pty(void)
{
    master_fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (master_fd < 0 || grantpt(master_fd) != 0 || unlockpt(master_fd) != 0) {
        fprintf(stderr, "thermal_box: cannot create a pseudo-terminal: %s\n", strerror(errno));
        return false;
    }
    const char *path = ptsname(master_fd);
    if (path == NULL) {
        fprintf(stderr, "thermal_box: ptsname failed: %s\n", strerror(errno));
        return false;
    }
    slave_fd = open(path, O_RDWR | O_NOCTTY);
    struct termios t;
    if (slave_fd < 0 || tcgetattr(slave_fd, &t) != 0) {
        fprintf(stderr, "thermal_box: cannot open %s: %s\n", path, strerror(errno));
        return false;
    }
    cfmakeraw(&t);
    cfsetispeed(&t, B115200);
    cfsetospeed(&t, B115200);
    if (tcsetattr(slave_fd, TCSANOW, &t) != 0) {
        fprintf(stderr, "thermal_box: cannot set %s raw: %s\n", path, strerror(errno));
        return false;
    }
    return true;
}

bool native_uart_open(int inherited_fd)
{
    if (inherited_fd >= 0) {
        master_fd = inherited_fd;
        if (fcntl(master_fd, F_SETFD, FD_CLOEXEC) != 0 || ptsname(master_fd) == NULL) {
            fprintf(stderr, "thermal_box: --pty-fd %d is not a pseudo-terminal master\n",
                    inherited_fd);
            return false;
        }
    } else if (!create_pty()) {
        return false;
    }
    if (!set_nonblocking(master_fd)) {
        return false;
    }
    printf("PTY %s\n", ptsname(master_fd));
    fflush(stdout);
    return true;
}

int native_uart_fd(void)
{
    return master_fd;
}

void hal_uart_write(const uint8_t *data, size_t len)
{
    /* Like the box's transmit: wait while the pty is full, never drop (the HIL counts lines). */
    while (len > 0u) {
        ssize_t n = write(master_fd, data, len);
        if (n > 0) {
            data += n;
            len -= (size_t)n;
            continue;
        }
        if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
            fprintf(stderr, "thermal_box: pty write failed (%zu bytes of a line unsent): %s\n",
                    len, strerror(errno));
            exit(1);
        }
        /* Full (or a zero-length write): wait until the reader has taken some. */
        struct pollfd p = {.fd = master_fd, .events = POLLOUT};
        int r = poll(&p, 1, 1000);
        if (r < 0 && errno != EINTR) {
            fprintf(stderr, "thermal_box: poll on the pty failed: %s\n", strerror(errno));
            exit(1);
        }
        if (r > 0 && (p.revents & POLLNVAL)) {
            fprintf(stderr, "thermal_box: the pty was closed under the firmware\n");
            exit(1);
        }
    }
}

size_t hal_uart_read(uint8_t *buf, size_t max)
{
    ssize_t n = read(master_fd, buf, max);
    return n > 0 ? (size_t)n : 0u;
}
