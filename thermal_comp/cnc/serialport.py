"""The box's serial port for the thermalcomp component: opened raw with the standard library
(no pyserial under LinuxCNC's /usr/bin/python3), read into whole lines with a bounded buffer.
"""

from __future__ import annotations

import os
import termios

# A receive buffer this long without a newline is discarded up to the next newline (a box line
# is at most a few hundred bytes): a stream without newlines must not grow memory or read time.
MAX_LINE_BYTES = 4096
OVERLONG = b"<over-long line>"  # what Port.read_lines returns for a discarded over-long line


class Port:
    """The box's serial port, opened raw with the standard library (no pyserial needed)."""

    def __init__(self, path: str, baud: int) -> None:
        self.path, self.baud = path, baud
        self.fd: int | None = None
        self.buf = bytearray()
        self.synced = False  # the bytes before the first newline after opening are dropped
        self.discarding = False  # an over-long line is being dropped up to its newline

    def open(self) -> bool:
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            return False
        try:
            attrs = termios.tcgetattr(fd)
            attrs[0] = 0  # iflag: no CR/LF translation, no flow control
            attrs[1] = 0  # oflag: raw output
            attrs[2] = termios.CS8 | termios.CREAD | termios.CLOCAL
            attrs[3] = 0  # lflag: no echo, no canonical mode
            speed = getattr(termios, f"B{self.baud}", termios.B115200)
            attrs[4] = attrs[5] = speed
            attrs[6][termios.VMIN], attrs[6][termios.VTIME] = 0, 0
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
        except termios.error:
            pass  # not a tty (a FIFO in a bench): read it as it is
        self.fd, self.buf, self.synced, self.discarding = fd, bytearray(), False, False
        return True

    def close(self) -> None:
        if self.fd is not None:
            try:
                os.close(self.fd)
            except OSError:
                pass
        self.fd = None

    def read_lines(self) -> list[bytes] | None:
        """Complete lines received so far (without CR LF); None when the port went away.

        A line that grows beyond MAX_LINE_BYTES without a newline comes out once as OVERLONG
        (as soon as it is that long) and the rest of it, up to the next newline, is dropped."""
        assert self.fd is not None
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return []
        except OSError:
            return None  # EIO: the other side (box, USB adapter) is gone
        if not data:
            return None
        return self.feed(data)

    def feed(self, data: bytes) -> list[bytes]:
        """Split received bytes into lines (read_lines without the port, for the tests)."""
        out: list[bytes] = []
        start = 0
        while (nl := data.find(b"\n", start)) >= 0:
            chunk = data[start:nl]
            start = nl + 1
            if self.discarding:
                self.discarding, self.synced = False, True
            elif not self.synced:
                self.synced = True  # the bytes before the first newline after opening
            elif len(self.buf) + len(chunk) > MAX_LINE_BYTES:
                out.append(OVERLONG)
            else:
                out.append((bytes(self.buf) + chunk).rstrip(b"\r"))
            self.buf.clear()
        rest = data[start:]
        if not self.discarding:
            if len(self.buf) + len(rest) > MAX_LINE_BYTES:
                self.discarding = True
                self.buf.clear()
                out.append(OVERLONG)
            else:
                self.buf += rest
        return out

    def write(self, data: bytes) -> bool:
        if self.fd is None:
            return False
        try:
            os.write(self.fd, data)
            return True
        except OSError:
            return False
