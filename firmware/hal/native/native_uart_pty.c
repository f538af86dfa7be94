/* UART HAL of the native board: a pseudo-terminal. The slave side is set raw and kept open by
 * this process, so the line discipline never echoes or translates bytes and the master never
 * reports a hang-up before the runner has opened the port. */
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

bool native_uart_open(void)
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
    int flags = fcntl(master_fd, F_GETFL);
    if (flags < 0 || fcntl(master_fd, F_SETFL, flags | O_NONBLOCK) != 0) {
        fprintf(stderr, "thermal_box: fcntl: %s\n", strerror(errno));
        return false;
    }
    printf("PTY %s\n", path);
    fflush(stdout);
    return true;
}

int native_uart_fd(void)
{
    return master_fd;
}

void hal_uart_write(const uint8_t *data, size_t len)
{
    /* Like the box's transmit queue: wait while full, never drop (the HIL counts lines). */
    while (len > 0u) {
        ssize_t n = write(master_fd, data, len);
        if (n > 0) {
            data += n;
            len -= (size_t)n;
        } else if (n < 0 && errno != EAGAIN && errno != EINTR) {
            fprintf(stderr, "thermal_box: pty write failed: %s\n", strerror(errno));
            exit(1);
        } else {
            struct pollfd p = {.fd = master_fd, .events = POLLOUT};
            (void)poll(&p, 1, -1);
        }
    }
}

size_t hal_uart_read(uint8_t *buf, size_t max)
{
    ssize_t n = read(master_fd, buf, max);
    return n > 0 ? (size_t)n : 0u;
}
