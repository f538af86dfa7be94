/* Retained memory of the native board: the backup SRAM of docs/native-board.md. A static
 * buffer survives the board's own watchdog reset (the firmware restarts in-process); with
 * --retain FILE it is also kept in FILE, so a box process killed and started again with
 * --wdt-reset and the same FILE resumes like a box after a watchdog or brown-out reset. A
 * power cut without a backup battery is a missing or deleted FILE. */
#define _POSIX_C_SOURCE 200809L
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "hal_retain.h"
#include "native_board.h"

#define RETAIN_BYTES 4096u

static uint8_t retained[RETAIN_BYTES];
static int retain_fd = -1;

bool native_set_retain_file(const char *path)
{
    retain_fd = open(path, O_RDWR | O_CREAT, 0600);
    if (retain_fd < 0) {
        return false;
    }
    ssize_t got = pread(retain_fd, retained, sizeof retained, 0);
    if (got < (ssize_t)sizeof retained) {
        /* new or short file: what a power cut leaves (the application sees no valid block) */
        memset(retained + (got > 0 ? got : 0), 0, sizeof retained - (size_t)(got > 0 ? got : 0));
    }
    return true;
}

size_t hal_retain_size(void)
{
    return sizeof retained;
}

void hal_retain_read(size_t offset, void *dst, size_t n)
{
    if (offset >= sizeof retained) {
        return;
    }
    memcpy(dst, retained + offset, n <= sizeof retained - offset ? n : sizeof retained - offset);
}

void hal_retain_write(size_t offset, const void *src, size_t n)
{
    if (offset >= sizeof retained) {
        return;
    }
    size_t k = n <= sizeof retained - offset ? n : sizeof retained - offset;
    memcpy(retained + offset, src, k);
    if (retain_fd >= 0 && pwrite(retain_fd, retained + offset, k, (off_t)offset) != (ssize_t)k) {
        fputs("thermal_box: writing the retained-memory file failed\n", stderr);
    }
}
