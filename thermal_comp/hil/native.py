"""Start the native firmware (BOARD=native) and connect to it like to a real box.

docs/native-board.md is the contract: the binary prints ``PTY <slave path>`` on stdout, reads
feed commands (``S``, ``F``, ``Q``) on stdin and speaks the wire protocol on the pty. This
module is only process glue; what is sent and checked lives in hil.runner.

The runner creates the pseudo-terminal itself and hands the master to the firmware
(``--pty-fd``), keeping the slave open for as long as the session lasts; pyserial opens that
very descriptor through ``/proc/self/fd/<n>``. A ``/dev/pts/N`` path is never opened: the
kernel reuses pty numbers as soon as their owner exits, so between a power cut and the next
boot (or with tests running in parallel) a path could lead to another process's port.
"""

from __future__ import annotations

import os
import select
import subprocess
import tempfile
import termios
import time
import tty
from pathlib import Path

from thermal_comp.hil.link import SerialLink


class BoxStartError(RuntimeError):
    """The firmware did not start or did not announce its serial port."""


class NativeBox:
    """One running native firmware process: ``feed`` goes to stdin, ``link`` is its UART."""

    def __init__(self, binary: str | Path, wdt_reset: bool = False,
                 start_timeout: float = 10.0, retain: str | Path | None = None) -> None:
        self.binary = Path(binary)
        if not self.binary.is_file():
            raise BoxStartError(f"{self.binary}: firmware binary not found (build it first)")
        # The pty pair is ours: the firmware gets the master, we keep the slave.
        master, self._slave = os.openpty()
        try:
            tty.setraw(self._slave, termios.TCSANOW)
            args = [str(self.binary), "--pty-fd", str(master)]
            if wdt_reset:
                args.append("--wdt-reset")
            if retain is not None:  # the backup SRAM, kept across a warm reset
                args += ["--retain", str(retain)]
            # stderr goes to a file, not a pipe nobody drains (a chatty binary would block).
            self._stderr = tempfile.TemporaryFile()
            self.proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         stderr=self._stderr, bufsize=0, pass_fds=(master,))
        except BaseException:
            os.close(self._slave)
            raise
        finally:
            os.close(master)  # only the firmware holds it: its exit hangs the port up
        try:
            self.pty_path = self._read_pty_line(start_timeout)
            # Open the port before anything is fed (pyserial flushes input on open), by our
            # own descriptor: no other process can have been given it.
            self.link = SerialLink(f"/proc/self/fd/{self._slave}")
        except BaseException:
            self.kill()
            raise

    def _read_pty_line(self, timeout: float) -> str:
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        buf = b""
        deadline = time.monotonic() + timeout
        while b"\n" not in buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BoxStartError(f"{self.binary}: no 'PTY <path>' line within {timeout:g} s")
            ready, _, _ = select.select([fd], [], [], left)
            if not ready:
                continue
            chunk = os.read(fd, 4096)
            if not chunk:
                code = self.proc.wait()
                raise BoxStartError(f"{self.binary}: exited (code {code}) before "
                                    f"announcing its pty: {self.stderr_text().strip()}")
            buf += chunk
        line = buf.split(b"\n", 1)[0].decode(errors="replace").strip()
        if not line.startswith("PTY "):
            raise BoxStartError(f"{self.binary}: expected 'PTY <path>' on stdout, got {line!r}")
        return line[4:].strip()

    # --- feed ------------------------------------------------------------------------------
    def feed(self, data: bytes) -> None:
        """Write feed commands (already formatted lines) to the firmware's stdin."""
        assert self.proc.stdin is not None
        try:
            self.proc.stdin.write(data)
        except BrokenPipeError:
            raise BoxStartError(f"{self.binary}: exited (code {self.proc.poll()}) while being "
                                f"fed") from None

    def alive(self) -> bool:
        return self.proc.poll() is None

    # --- shutdown --------------------------------------------------------------------------
    def stop(self, timeout: float = 5.0) -> int:
        """Ask the firmware to exit (``Q``), wait, and return its exit code."""
        if self.alive() and self.proc.stdin is not None:
            try:
                self.proc.stdin.write(b"Q\n")
                self.proc.stdin.close()
            except BrokenPipeError:
                pass
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            code = self.proc.wait()
        self._close_link()
        return code

    def kill(self) -> int:
        """Power cut: the process dies without a chance to flush anything; its exit code."""
        if self.alive():
            self.proc.kill()
        code = self.proc.wait()
        self._close_link()
        return code

    def _close_link(self) -> None:
        link = getattr(self, "link", None)
        if link is not None:
            link.close()
        if getattr(self, "_slave", -1) >= 0:
            os.close(self._slave)
            self._slave = -1
        for stream in (self.proc.stdin, self.proc.stdout):
            if stream is not None and not stream.closed:
                try:
                    stream.close()
                except OSError:
                    pass

    def stderr_text(self) -> str:
        """What the firmware wrote on stderr so far (for error messages)."""
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace")

    def last_words(self) -> str:
        """The last line the firmware wrote on stderr: why a box that died stopped."""
        lines = self.stderr_text().strip().splitlines()
        return lines[-1] if lines else ""

    def __enter__(self) -> NativeBox:
        return self

    def __exit__(self, *exc: object) -> None:
        self.kill() if exc[0] is not None else self.stop()
