"""The box's serial line with a recorder in the middle, and the box process itself, for the
`make cnc` driver (cnc/driver.py): the tap decodes every line the box sends with the
project's decoder, can corrupt, drop or inject bytes, and hands the rest to the component.
Standard library and the stdlib-only contract only (LinuxCNC's /usr/bin/python3)."""

from __future__ import annotations

import os
import select
import subprocess
import threading
import time
import tty
from pathlib import Path

from thermal_comp.contract import protocol


class DriverError(RuntimeError):
    """The session could not be carried out (names the step)."""


class Tap:
    """The box's serial line with a recorder in the middle (box pty <-> component pty).

    Its ends can change while it runs, always inside its own thread (``call``): the box's end
    when the box restarts (a new process announces a new pty), the component's end when the
    link drops (both pty ends closed, the symlink removed: the component's read fails) and
    comes back (a new pty behind the same symlink). Bytes can be injected towards the
    component (a forged line, garbage)."""

    def __init__(self, box_pty: str, link_path: Path) -> None:
        self.box_fd: int | None = None
        self.master: int | None = None
        self.slave: int | None = None
        self.link_path = link_path
        self.samples: list[dict] = []  # every $C line the box sent, decoded, in order
        self.replies: list[str] = []  # every other line the box sent
        self.commands: list[str] = []  # every line the component sent
        self.times: list[tuple[float, str, str]] = []  # (when, > sent / < box, line) but $C
        self.corrupt_next = False
        self.cond = threading.Condition()
        self.stop = False
        self._calls: list[tuple[object, threading.Event, list]] = []
        self._from_box = bytearray()
        self._from_comp = bytearray()
        self._attach_box(box_pty)
        self._open_link()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    # the ends, changed only in the tap's thread (or before it starts)
    def _attach_box(self, box_pty: str) -> None:
        self.box_fd = os.open(box_pty, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.box_fd)
        self._from_box = bytearray()

    def _detach_box(self) -> None:
        if self.box_fd is not None:
            _close(self.box_fd)
        self.box_fd = None

    def _open_link(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # no echo, no CR/LF mangling before the component opens it
        if self.link_path.is_symlink() or self.link_path.exists():
            self.link_path.unlink()
        self.link_path.symlink_to(os.ttyname(self.slave))
        self._from_comp = bytearray()

    def _drop_link(self) -> None:
        """The cable is pulled: both ends of the component's pty closed, the port gone."""
        if self.link_path.is_symlink():
            self.link_path.unlink()
        for fd in (self.master, self.slave):
            if fd is not None:
                _close(fd)
        self.master = self.slave = None

    def _inject(self, data: bytes) -> None:
        if self.master is not None:
            os.write(self.master, data)

    def call(self, fn, *args, timeout: float = 10.0):
        """Run ``fn(*args)`` in the tap's thread, between two reads; its result."""
        done, out = threading.Event(), []
        with self.cond:
            self._calls.append((lambda: out.append(fn(*args)), done, out))
        if not done.wait(timeout):
            raise DriverError(f"the tap did not run {getattr(fn, '__name__', fn)}")
        if out and isinstance(out[-1], BaseException):
            raise out[-1]
        return out[0] if out else None

    def attach_box(self, box_pty: str) -> None:
        self.call(self._attach_box, box_pty)

    def detach_box(self) -> None:
        self.call(self._detach_box)

    def drop_link(self) -> None:
        self.call(self._drop_link)

    def restore_link(self) -> None:
        self.call(self._open_link)

    def inject(self, data: bytes) -> None:
        self.call(self._inject, data)

    def _run(self) -> None:
        while not self.stop:
            with self.cond:
                calls, self._calls = self._calls, []
            for fn, done, out in calls:
                try:
                    fn()
                except Exception as exc:  # handed to the caller
                    out.append(exc)
                done.set()
            fds = [fd for fd in (self.box_fd, self.master) if fd is not None]
            ready, _, _ = select.select(fds, [], [], 0.02)
            for fd in ready:
                try:
                    data = os.read(fd, 65536)
                except OSError:
                    data = b""
                if fd == self.box_fd:
                    if not data:  # the box's process is gone (killed): wait for the next
                        self._detach_box()
                        continue
                    self._box_bytes(data)
                elif fd == self.master and data:
                    self._from_comp += data
                    *done, rest = bytes(self._from_comp).split(b"\n")
                    self._from_comp = bytearray(rest)
                    with self.cond:
                        self.commands += [d.rstrip(b"\r").decode(errors="replace") for d in done]
                        self.times += [(time.monotonic(), ">", d.rstrip(b"\r").decode(
                            errors="replace")) for d in done]
                    if self.box_fd is not None:
                        os.write(self.box_fd, data)

    def _box_bytes(self, data: bytes) -> None:
        self._from_box += data
        *done, rest = bytes(self._from_box).split(b"\n")
        self._from_box = bytearray(rest)
        out = bytearray()
        for line in done:
            raw = line.rstrip(b"\r")
            sent = line + b"\n"
            record: dict | None = None
            if raw.startswith(b"$C,"):
                msg = protocol.decode(raw)  # the box's own line: it must decode
                record = {"seq": msg.seq, "status": msg.status,
                          "corr_nm": list(msg.corrections_nm), "corrupted": False,
                          "temps": list(msg.temp_codes), "t": time.monotonic(),
                          "delivered": self.master is not None}
                if self.corrupt_next:
                    self.corrupt_next = False
                    record["corrupted"] = True
                    sent = _corrupt(line) + b"\n"
            out += sent
            with self.cond:
                if record is not None:
                    self.samples.append(record)
                else:
                    self.replies.append(raw.decode(errors="replace"))
                    self.times.append((time.monotonic(), "<", raw.decode(errors="replace")))
                self.cond.notify_all()
        if out and self.master is not None:  # a dropped link loses what the box sent
            os.write(self.master, bytes(out))

    def wait(self, pred, timeout: float, what: str):
        deadline = time.monotonic() + timeout
        with self.cond:
            while not pred():
                left = deadline - time.monotonic()
                if left <= 0:
                    raise DriverError(f"timed out after {timeout:g} s waiting for {what}")
                self.cond.wait(min(left, 0.05))

    def close(self) -> None:
        self.stop = True
        self.thread.join(2.0)
        self._detach_box()
        self._drop_link()


def _close(fd: int) -> None:
    try:
        os.close(fd)
    except OSError:
        pass


def _corrupt(line: bytes) -> bytes:
    """Flip the last digit of the line's first correction (the CRC no longer matches)."""
    fields = line.split(b",")
    f = bytearray(fields[4])  # $C,seq,status,n_axes,corr0,...
    i = len(f) - 1 if f[-1:].isdigit() else len(f) - 2
    f[i] = ord("1") if f[i] != ord("1") else ord("2")
    fields[4] = bytes(f)
    return b",".join(fields)


class Box:
    """The native firmware process: feed on stdin, UART on the pty it announces."""

    def __init__(self, binary: str, options: tuple[str, ...] = ()) -> None:
        self.proc = subprocess.Popen([binary, *options], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0)
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], 10.0)
        first = self.proc.stdout.readline().decode(errors="replace") if ready else ""
        if not first.startswith("PTY "):
            self.proc.kill()
            raise DriverError(f"{binary}: expected 'PTY <path>' on stdout, got {first!r}")
        self.pty = first.split()[1]

    def feed(self, text: str) -> None:
        assert self.proc.stdin is not None
        try:
            self.proc.stdin.write(text.encode("ascii"))
        except BrokenPipeError:
            raise DriverError(f"the box exited (code {self.proc.poll()}) while being fed: "
                              f"{self.stderr()}") from None

    def stderr(self) -> str:
        if self.proc.poll() is None or self.proc.stderr is None:
            return ""
        return self.proc.stderr.read().decode(errors="replace").strip()[-500:]

    def kill(self) -> int:
        """A power cut (or the watchdog's reset): the process dies between two samples."""
        self.proc.kill()
        code = self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout):
            try:
                stream.close()  # type: ignore[union-attr]
            except OSError:
                pass
        return code

    def stop(self) -> int:
        if self.proc.poll() is not None:
            return self.proc.returncode
        try:
            self.feed("Q\n")
            self.proc.stdin.close()  # type: ignore[union-attr]
        except (DriverError, OSError):
            pass
        try:
            return self.proc.wait(5.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()
