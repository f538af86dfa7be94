"""Helpers for the fleet tests: a box on a pty that answers INFO/STATUS/ZERO, and waiting."""

from __future__ import annotations

import os
import threading
import time
import tty
from collections.abc import Callable

from thermal_comp.contract import protocol

INFO = protocol.Info("1.4.0", "a1b2c3d4", True, 1000, ("dx_um", "dz_um"),
                     (protocol.Channel(0, "T01", "K"), protocol.Channel(1, "T02", "K")))


def wait_for(cond: Callable[[], object], timeout_s: float = 10.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what or cond}")


class PtyBox:
    """The box's side of a pty: answers INFO and STATUS, acknowledges ZERO, records commands;
    ``send(line)`` writes a line as the box would."""

    def __init__(self, info: protocol.Info = INFO) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self._slave = slave
        self.info = info
        self.commands: list[str] = []
        self.seq = 0
        self._stop = False
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def send(self, line: bytes) -> None:
        os.write(self.master, line)

    def sample(self, status: int = 0, corr: tuple[int, ...] = (1500, -2500),
               codes: tuple[int, ...] = (2600, 2700)) -> None:
        self.send(protocol.encode_sample(self.seq, status, corr, codes))
        self.seq += 1

    def _serve(self) -> None:
        buf = b""
        while not self._stop:
            try:
                data = os.read(self.master, 256)
            except OSError:
                return
            buf += data
            while b"\n" in buf:
                line, _, buf = buf.partition(b"\n")
                cmd = line.strip().decode(errors="replace")
                self.commands.append(cmd)
                if cmd == "INFO":
                    self.send(protocol.encode_info(self.info))
                elif cmd == "STATUS":
                    self.send(protocol.encode_status(protocol.StatusReport(
                        0x22, self.seq, 10, (0x0001, 0), None)))
                elif cmd == "ZERO":
                    self.send(protocol.encode_line("OK", ["ZERO", self.seq]))

    def close(self) -> None:
        self._stop = True
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
