"""The box's serial port as the runner sees it: pyserial plus a reader thread that splits lines.

Why a thread: the firmware writes a line per sample while the runner is still feeding; reading
in the same thread as the feed would either stall the feed or let the pty buffer fill (then the
firmware blocks on its write and the whole loop runs lock-step at a fraction of the speed).
The thread reads with a large buffer and keeps every complete line, in arrival order, with a
condition variable the runner waits on.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import serial


class LinkTimeout(RuntimeError):
    """The box did not send what the runner waited for in time."""


class SerialLink:
    """Line-oriented reader/writer over one serial port (pty, /dev/ttyUSB0 or socket:// URL).

    ``lines`` holds every complete line received (without ``\\r\\n``), as bytes, in order.
    """

    READ_CHUNK = 1 << 16

    def __init__(self, port: str, baudrate: int = 115200, count_prefix: bytes = b"$C,") -> None:
        # pyserial flushes the input buffer on open: the runner opens the port before it feeds
        # anything, and asks (INFO) instead of relying on a banner.
        if "://" in port:
            self.port = serial.serial_for_url(port, baudrate=baudrate, timeout=0.05)
        else:
            self.port = serial.Serial(port, baudrate=baudrate, timeout=0.05)
        self.lines: list[bytes] = []
        self.count_prefix = count_prefix
        self.prefixed = 0  # how many lines started with count_prefix (sample lines)
        self._partial = bytearray()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self.spurious_empty_reads = 0  # tolerated empty reads (see _read_loop)
        self._thread = threading.Thread(target=self._read_loop, name="hil-serial", daemon=True)
        self._thread.start()

    # --- reading -------------------------------------------------------------------------
    # pyserial raises "device reports readiness to read but returned no data" when select()
    # said readable and read() returned nothing: the port was hung up (the box exited), or
    # another reader took the bytes (a reused /dev/pts path: NativeBox no longer opens one).
    # In 60 replays on a loaded machine every such read came after the box's last line (its
    # exit); none mid-run. A bounded run of them is tolerated anyway (a real hang-up keeps
    # failing and ends the loop), so one transient empty read cannot end a replay.
    SPURIOUS_EMPTY_READS = 50
    SPURIOUS_PAUSE_S = 0.01

    def _read_loop(self) -> None:
        empty = 0
        try:
            while not self._stop.is_set():
                try:
                    waiting = self.port.in_waiting
                    data = self.port.read(max(1, min(self.READ_CHUNK, waiting)))
                except serial.SerialException as exc:
                    if "returned no data" not in str(exc) or empty >= self.SPURIOUS_EMPTY_READS:
                        raise
                    empty += 1
                    self.spurious_empty_reads += 1
                    time.sleep(self.SPURIOUS_PAUSE_S)
                    continue
                if data:
                    empty = 0
                    self._take(data)
        except (OSError, serial.SerialException) as exc:
            # The box went away (process ended, pty closed): wake waiters, let them decide.
            if not self._stop.is_set():
                self._error = exc
        finally:
            with self._cond:
                self._cond.notify_all()

    def _take(self, data: bytes) -> None:
        self._partial += data
        if b"\n" not in data:
            return
        *complete, rest = bytes(self._partial).split(b"\n")
        self._partial = bytearray(rest)
        new = [line.rstrip(b"\r") for line in complete]
        hits = sum(1 for line in new if line.startswith(self.count_prefix))
        with self._cond:
            self.lines.extend(new)
            self.prefixed += hits
            self._cond.notify_all()

    @property
    def closed_error(self) -> BaseException | None:
        """Set when the port failed while reading (e.g. the firmware exited)."""
        return self._error

    def wait_for(self, predicate: Callable[[list[bytes]], bool], timeout: float,
                 what: str) -> None:
        """Block until ``predicate(lines)`` is true; LinkTimeout naming ``what`` otherwise."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while not predicate(self.lines):
                left = deadline - time.monotonic()
                if left <= 0:
                    raise LinkTimeout(f"timed out after {timeout:g} s waiting for {what} "
                                      f"({len(self.lines)} lines received)")
                if self._error is not None or not self._thread.is_alive():
                    if predicate(self.lines):
                        break
                    raise LinkTimeout(f"serial port closed while waiting for {what}: "
                                      f"{self._error}")
                self._cond.wait(min(left, 0.1))

    def wait_count(self, count: int, timeout: float, what: str = "lines") -> None:
        """Block until at least ``count`` lines have arrived in total."""
        self.wait_for(lambda lines: len(lines) >= count, timeout, f"{count} {what}")

    def wait_prefixed(self, count: int, timeout: float, what: str) -> None:
        """Block until at least ``count`` lines starting with ``count_prefix`` have arrived."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self.prefixed < count:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise LinkTimeout(f"timed out after {timeout:g} s waiting for {what} "
                                      f"({self.prefixed} of {count} received)")
                if self._error is not None or not self._thread.is_alive():
                    raise LinkTimeout(f"serial port closed while waiting for {what} "
                                      f"({self.prefixed} of {count} received): {self._error}")
                self._cond.wait(min(left, 0.1))

    def count(self) -> int:
        with self._cond:
            return len(self.lines)

    # --- writing -------------------------------------------------------------------------
    def write(self, data: bytes) -> None:
        self.port.write(data)
        self.port.flush()

    def command(self, text: str, reply_prefix: bytes, timeout: float = 5.0) -> bytes:
        """Send one command line and return the first new line starting with ``reply_prefix``."""
        start = self.count()
        self.write(text.encode("ascii") + b"\r\n")

        def found(lines: list[bytes]) -> bool:
            return any(line.startswith(reply_prefix) for line in lines[start:])

        self.wait_for(found, timeout, f"reply {reply_prefix!r} to {text!r}")
        with self._cond:
            return next(line for line in self.lines[start:] if line.startswith(reply_prefix))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        try:
            self.port.close()
        except (OSError, serial.SerialException):
            pass
