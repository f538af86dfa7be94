"""The cross-compiled STM32F405 image under ``qemu-system-arm -M netduinoplus2`` as a box.

Board variant ``qemu_uartfeed`` (firmware/boards/qemu_uartfeed/): the samples arrive on USART2
in the native board's feed format, because QEMU's SPI1 has nothing attached; USART1 speaks
the wire protocol as on the real box. QEMU's ``-serial`` options map in order to USART1,
USART2, ... (PLATFORM.md), so: USART1 = a pty the runner opens with pyserial (a pty, not a TCP
socket: QEMU writes every transmitted byte with its own syscall, which costs about three times
more as a TCP segment), USART2 = a TCP socket with ``nodelay``.

Start-up follows PLATFORM.md: QEMU starts halted (``-S``) with its monitor on stdin/stdout,
the runner connects both serial endpoints, then sends ``cont``. QEMU's pty backend notices a
reader only on a timer and drops what the guest writes before that, so the runner repeats
``INFO`` until the first answer arrives; nothing is fed before that.
"""

from __future__ import annotations

import os
import re
import select
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Sequence
from pathlib import Path

from thermal_comp.hil.build import build_firmware
from thermal_comp.hil.link import LinkTimeout, SerialLink
from thermal_comp.hil.native import BoxStartError

QEMU = "qemu-system-arm"
MACHINE = "netduinoplus2"


def qemu_available() -> bool:
    return shutil.which(QEMU) is not None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class QemuBox:
    """One QEMU process running the qemu_uartfeed image; same interface as NativeBox."""

    def __init__(self, elf: str | Path, start_timeout: float = 15.0,
                 extra_args: Sequence[str] = ()) -> None:
        if not qemu_available():
            raise BoxStartError(f"{QEMU} is not installed (apt-get install --no-install-"
                                "recommends qemu-system-arm)")
        self.elf = Path(elf)
        if not self.elf.is_file():
            raise BoxStartError(f"{self.elf}: firmware image not found (build it first)")
        port = _free_port()
        args = [QEMU, "-M", MACHINE, "-display", "none", "-S", "-monitor", "stdio",
                "-chardev", "pty,id=box", "-serial", "chardev:box",
                "-chardev", f"socket,id=feed,host=127.0.0.1,port={port},server=on,wait=off,"
                "nodelay=on", "-serial", "chardev:feed",
                "-kernel", str(self.elf), *extra_args]
        self.proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, bufsize=0)
        self.link: SerialLink | None = None
        self.feed_sock: socket.socket | None = None
        try:
            banner = self._read_until(b"(qemu)", start_timeout)
            m = re.search(rb"char device redirected to (\S+) \(label box\)", banner)
            if m is None:
                raise BoxStartError(f"{QEMU}: no pty announced: {banner.decode(errors='replace')}")
            self.pty_path = m.group(1).decode()
            self._drain = threading.Thread(target=self._drain_monitor, daemon=True)
            self._drain.start()
            self.link = SerialLink(self.pty_path)
            self.feed_sock = socket.create_connection(("127.0.0.1", port), timeout=start_timeout)
            self.feed_sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.feed_sock.settimeout(None)
            self._monitor("cont")
            self._wait_info(start_timeout)
        except BaseException:
            self.kill()
            raise

    def _read_until(self, marker: bytes, timeout: float) -> bytes:
        assert self.proc.stdout is not None
        fd, buf = self.proc.stdout.fileno(), b""
        deadline = time.monotonic() + timeout
        while marker not in buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BoxStartError(f"{QEMU}: no monitor prompt within {timeout:g} s: "
                                    f"{buf.decode(errors='replace')}")
            if select.select([fd], [], [], left)[0]:
                chunk = os.read(fd, 4096)
                if not chunk:
                    raise BoxStartError(f"{QEMU} exited (code {self.proc.wait()}): "
                                        f"{buf.decode(errors='replace')}")
                buf += chunk
        return buf

    def _drain_monitor(self) -> None:
        """Keep reading the monitor's echo so QEMU never blocks on a full stdout pipe."""
        try:
            while self.proc.stdout is not None and os.read(self.proc.stdout.fileno(), 4096):
                pass
        except (OSError, ValueError):
            pass

    def _monitor(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command.encode() + b"\n")

    def _wait_info(self, timeout: float) -> None:
        assert self.link is not None
        deadline = time.monotonic() + timeout
        while True:
            try:
                self.link.command("INFO", b"$I,", timeout=0.25)
                return
            except LinkTimeout:
                if time.monotonic() > deadline or not self.alive():
                    raise BoxStartError(f"{self.elf}: no answer to INFO on USART1 within "
                                        f"{timeout:g} s") from None

    # --- the Box interface used by hil.runner -----------------------------------------------
    def feed(self, data: bytes) -> None:
        assert self.feed_sock is not None
        try:
            self.feed_sock.sendall(data)
        except OSError as exc:
            raise BoxStartError(f"{QEMU}: feed socket failed: {exc}") from None

    def alive(self) -> bool:
        return self.proc.poll() is None

    def last_words(self) -> str:
        """Nothing: the STM32 image has no stderr (its faults travel in the status flags)."""
        return ""

    def stop(self, timeout: float = 5.0) -> int:
        if self.alive():
            try:
                self._monitor("quit")
            except (BrokenPipeError, OSError):
                pass
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            code = self.kill()
        self._close()
        return code

    def kill(self) -> int:
        if self.alive():
            self.proc.kill()
        code = self.proc.wait()
        self._close()
        return code

    def _close(self) -> None:
        if self.link is not None:
            self.link.close()
        if self.feed_sock is not None:
            self.feed_sock.close()
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            try:
                self.proc.stdin.close()
            except OSError:
                pass


def build_image(header: str | Path, build_root: str | Path, cflags: str = "") -> Path:
    """The qemu_uartfeed ELF for a header (same firmware Makefile, same flags)."""
    return build_firmware(header, build_root, "qemu_uartfeed", cflags)


def box_factory(setup, build_dir: str | Path | None = None, cflags: str = ""):
    """A ``start_box`` for hil.runner.replay that boots the QEMU image of ``setup``'s model."""
    root = Path(build_dir) if build_dir is not None else setup.build.header_path.parent
    elf = build_image(setup.build.header_path, root, cflags)

    def start(wdt_reset: bool) -> QemuBox:
        if wdt_reset:
            raise BoxStartError("QEMU's netduinoplus2 does not model the reset-cause flags: "
                                "a watchdog restart can only be replayed on the native board")
        return QemuBox(elf)

    return start
