"""`host monitor`: watch a running box (or the HIL's pty) live, and log what it sends.

Why it exists: at the machine, the first questions are "is the right model on this box?", "what
is it correcting right now?" and "is any thermocouple faulted?". The monitor asks INFO, checks
the model hash against the model.json the user has, then shows the corrections, the channel
temperatures and the status flags as they arrive. A box on a factory floor sends noise and gets
unplugged: bad lines are counted and shown, never fatal, and a lost port is reopened.
"""

from __future__ import annotations

import csv
import io
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import serial

from contract import protocol
from contract.errors import InputError

RETRY_S = 1.0
INFO_TIMEOUT_S = 1.0
INFO_ATTEMPTS = 3
REDRAW_S = 0.1


class MonitorError(InputError):
    """Bad monitor input (unreadable model, a log file with another layout, a port that
    cannot be opened at start)."""


@dataclass
class MonitorState:
    """Everything the display shows; updated by the reader, rendered by ``render``."""

    port: str
    info: protocol.Info | None = None
    expected_hash: str | None = None
    sample: protocol.Sample | None = None
    samples: int = 0
    bad_lines: int = 0
    last_bad: str = ""
    seq_gaps: int = 0
    reconnects: int = 0
    connected: bool = False
    last_rx: float | None = None
    messages: list[str] = field(default_factory=list)
    # sensor -> (window_lo, window_hi) codes from model.json (codegen's EXTRAP windows); used
    # only while the box reports that model's hash, to name the channels behind EXTRAP
    windows: dict[str, tuple[int, int]] = field(default_factory=dict)

    @property
    def hash_ok(self) -> bool | None:
        if self.expected_hash is None or self.info is None:
            return None
        return self.info.model_hash == self.expected_hash

    def axis_names(self, n: int) -> list[str]:
        names = list(self.info.axes) if self.info else []
        return names[:n] + [f"axis{i}" for i in range(len(names), n)]

    def channel_names(self, n: int) -> list[str]:
        names = [c.sensor for c in self.info.channels] if self.info else []
        return names[:n] + [f"ch{i}" for i in range(len(names), n)]

    def beyond_training(self) -> list[str]:
        """Channels of the current sample outside their training window (named only when the
        box runs the model.json the windows came from)."""
        s = self.sample
        if s is None or not self.windows or self.hash_ok is not True:
            return []
        names = self.channel_names(len(s.temp_codes))
        return [n for n, code in zip(names, s.temp_codes, strict=True)
                if n in self.windows and not self.windows[n][0] <= code <= self.windows[n][1]]


def _flags(state: MonitorState, sep: str) -> str:
    """The status flags of the current sample; EXTRAP names its channels when it can."""
    assert state.sample is not None
    names = protocol.status_names(state.sample.status)
    beyond = state.beyond_training() if "EXTRAP" in names else []
    if beyond:
        names = [f"EXTRAP({'+'.join(beyond)})" if n == "EXTRAP" else n for n in names]
    return sep.join(names) or "ok"


def _hash_line(state: MonitorState) -> str:
    if state.info is None:
        return "model: (no INFO reply yet)"
    info = state.info
    text = (f"firmware {info.fw_version}, model {info.model_hash} "
            f"(CRC {'OK' if info.crc_ok else 'BAD'}), period {info.period_ms} ms")
    if state.hash_ok is True:
        text += ", matches model.json"
    elif state.hash_ok is False:
        text += f", MISMATCH: model.json is {state.expected_hash}"
    return text


def render(state: MonitorState, now: float) -> list[str]:
    """The live screen as lines (the ANSI display redraws exactly these)."""
    lines = [f"host monitor on {state.port}: "
             + ("connected" if state.connected else "DISCONNECTED, retrying"),
             _hash_line(state)]
    s = state.sample
    if s is None:
        lines.append("no sample yet")
    else:
        age = "" if state.last_rx is None else f", {now - state.last_rx:.1f} s ago"
        lines.append(f"sample #{s.seq}{age}   status {s.status:04X}: {_flags(state, ', ')}")
        for name, nm in zip(state.axis_names(len(s.corrections_nm)), s.corrections_nm,
                            strict=True):
            lines.append(f"  correction {name:>10}: {nm / 1000.0:+10.3f} µm")
        temps = [f"{name} {code / 128.0:7.2f} °C" for name, code in
                 zip(state.channel_names(len(s.temp_codes)), s.temp_codes, strict=True)]
        for i in range(0, len(temps), 4):
            lines.append("  " + "   ".join(temps[i:i + 4]))
    lines.append(f"samples {state.samples}   bad lines {state.bad_lines}   "
                 f"seq gaps {state.seq_gaps}   reconnects {state.reconnects}")
    if state.last_bad:
        lines.append(f"  last bad line: {state.last_bad}")
    return lines


def plain_sample_line(state: MonitorState) -> str:
    """One line per sample when the output is not a terminal (logs, pipes, scripts)."""
    s = state.sample
    assert s is not None
    corr = " ".join(f"{n}={nm / 1000.0:+.3f}um" for n, nm in
                    zip(state.axis_names(len(s.corrections_nm)), s.corrections_nm, strict=True))
    temps = " ".join(f"{n}={c / 128.0:.2f}C" for n, c in
                     zip(state.channel_names(len(s.temp_codes)), s.temp_codes, strict=True))
    flags = _flags(state, ",")
    return (f"seq={s.seq} status={s.status:04X}[{flags}] {corr} {temps} "
            f"bad={state.bad_lines}".replace("  ", " "))


class CsvLog:
    """Appends samples as CSV; the header is fixed by the first sample's layout and checked
    against an existing file so two layouts never mix in one log."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._fh: TextIO | None = None
        self._writer = None
        self.header: list[str] | None = None

    def write(self, state: MonitorState, received: float) -> None:
        s = state.sample
        assert s is not None
        period_s = state.info.period_ms / 1000.0 if state.info else 1.0
        header = (["time_s", "seq", "status"]
                  + [f"corr_{n}" for n in state.axis_names(len(s.corrections_nm))]
                  + state.channel_names(len(s.temp_codes)) + ["host_unix_s"])
        if self._fh is None:
            self._open(header)
        elif header != self.header:
            raise MonitorError(f"{self.path}: the box's layout changed ({', '.join(header)}); "
                               "start a new --log file")
        assert self._writer is not None and self._fh is not None
        self._writer.writerow([f"{s.seq * period_s:.6g}", s.seq, f"{s.status:04X}"]
                              + [f"{nm / 1000.0:.3f}" for nm in s.corrections_nm]
                              + [f"{c / 128.0:.4f}" for c in s.temp_codes]
                              + [f"{received:.3f}"])
        self._fh.flush()

    def _open(self, header: list[str]) -> None:
        existing = None
        if self.path.is_file() and self.path.stat().st_size > 0:
            with self.path.open(newline="") as fh:
                existing = next(csv.reader(fh), None)
            if existing != header:
                raise MonitorError(f"{self.path}: existing log has columns "
                                   f"{', '.join(existing or [])}, the box sends "
                                   f"{', '.join(header)}; use another --log file")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = self.path.open("a", newline="")
        self._writer = csv.writer(self._fh)
        if existing is None:
            self._writer.writerow(header)
        self.header = header

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()


def open_port(port: str, baud: int) -> serial.SerialBase:
    """A pyserial port (device path, pty, or a pyserial URL such as socket://host:port)."""
    if "://" in port:
        return serial.serial_for_url(port, baudrate=baud, timeout=0.05)
    return serial.Serial(port, baudrate=baud, timeout=0.05)


class Monitor:
    """Reads lines from the box, keeps ``state`` current, shows it and logs samples.

    ``count``/``duration`` stop it for scripts; ``ansi`` redraws in place (default: when
    ``out`` is a terminal), else one plain line per sample and per event.
    """

    def __init__(self, port: str, baud: int = 115200, expected_hash: str | None = None,
                 windows: dict[str, tuple[int, int]] | None = None,
                 log: str | Path | None = None, count: int | None = None,
                 duration: float | None = None, out: TextIO | None = None,
                 ansi: bool | None = None, retry_s: float = RETRY_S,
                 opener: Callable[[str, int], serial.SerialBase] = open_port) -> None:
        self.port_name = port
        self.baud = baud
        self.count = count
        self.duration = duration
        self.out = sys.stdout if out is None else out
        self.ansi = self.out.isatty() if ansi is None else ansi
        self.retry_s = retry_s
        self.opener = opener
        self.state = MonitorState(port, expected_hash=expected_hash, windows=dict(windows or {}))
        self.log = CsvLog(log) if log else None
        self._port: serial.SerialBase | None = None
        self._buf = bytearray()
        self._drawn = 0
        self._last_draw = 0.0
        self._info_sent_at: float | None = None
        self._info_attempts = 0
        self._next_retry = 0.0
        self._pending: list[tuple[protocol.Sample, float]] = []

    # ---- life cycle ------------------------------------------------------------------------
    def run(self) -> int:
        """Monitor until count/duration is reached (or Ctrl-C); 1 if the model check failed."""
        start = time.monotonic()
        try:
            self._port = self.opener(self.port_name, self.baud)
        except (OSError, serial.SerialException) as exc:
            raise MonitorError(f"{self.port_name}: cannot open serial port: {exc}") from None
        self._connected()
        try:
            while not self._done(start):
                if self._port is None:
                    self._reconnect(start)
                    continue
                try:
                    self._poll()
                except (OSError, serial.SerialException) as exc:
                    self._lost(exc)
                self._draw()
        except KeyboardInterrupt:
            pass
        finally:
            self._flush_pending(force=True)
            self._draw(force=True)
            if self._port is not None:
                self._port.close()
            if self.log:
                self.log.close()
        st = self.state
        self._emit(f"monitor: {st.samples} samples, {st.bad_lines} bad lines, {st.seq_gaps} seq "
                   f"gaps, {st.reconnects} reconnects", final=True)
        if st.hash_ok is False or (st.info is not None and not st.info.crc_ok):
            return 1
        return 0

    def _done(self, start: float) -> bool:
        if self.count is not None and self.state.samples >= self.count:
            return True
        return self.duration is not None and time.monotonic() - start >= self.duration

    def _connected(self) -> None:
        self.state.connected = True
        self._buf.clear()
        self._info_attempts = 0
        self._ask_info()
        self._event(f"connected to {self.port_name}")

    def _lost(self, exc: BaseException) -> None:
        self._event(f"connection lost ({exc}); retrying every {self.retry_s:g} s")
        try:
            if self._port is not None:
                self._port.close()
        except (OSError, serial.SerialException):
            pass
        self._port = None
        self.state.connected = False
        self._next_retry = time.monotonic() + self.retry_s

    def _reconnect(self, start: float) -> None:
        wait = self._next_retry - time.monotonic()
        if wait > 0:
            remaining = None if self.duration is None else self.duration - (
                time.monotonic() - start)
            time.sleep(max(0.0, min(wait, 0.05 if remaining is None else remaining, 0.05)))
            return
        try:
            self._port = self.opener(self.port_name, self.baud)
        except (OSError, serial.SerialException):
            self._next_retry = time.monotonic() + self.retry_s
            return
        self.state.reconnects += 1
        self.state.info = None  # the box may have been swapped or reflashed: ask again
        self._connected()

    # ---- reading ---------------------------------------------------------------------------
    def _ask_info(self) -> None:
        assert self._port is not None
        self._port.write(b"INFO\r\n")
        self._port.flush()
        self._info_sent_at = time.monotonic()
        self._info_attempts += 1

    def _poll(self) -> None:
        port = self._port
        assert port is not None
        data = port.read(max(1, min(4096, port.in_waiting)))
        now = time.monotonic()
        if self.state.info is None and self._info_sent_at is not None \
                and now - self._info_sent_at > INFO_TIMEOUT_S:
            if self._info_attempts < INFO_ATTEMPTS:
                self._ask_info()
            else:
                self._info_sent_at = None
                self._event("no INFO reply: showing samples without names")
                self._flush_pending(force=True)
        if not data:
            return
        self._buf += data
        while b"\n" in self._buf:
            line, _, rest = bytes(self._buf).partition(b"\n")
            self._buf = bytearray(rest)
            self._handle(line.rstrip(b"\r"), now)
        if len(self._buf) > 1024:  # noise without newlines: drop it, count it
            self._bad(bytes(self._buf[:60]), "no end of line in 1024 bytes")
            self._buf.clear()

    def _handle(self, raw: bytes, now: float) -> None:
        if not raw.strip():
            return
        try:
            message = protocol.decode(raw)
        except protocol.ProtocolError as exc:
            self._bad(raw, str(exc))
            return
        self.state.last_rx = now
        if isinstance(message, protocol.Info):
            self.state.info = message
            self._info_sent_at = None
            self._event(_hash_line(self.state))
            self._flush_pending(force=True)
        elif isinstance(message, protocol.Sample):
            self._pending.append((message, time.time()))
            self._flush_pending(force=False)

    def _bad(self, raw: bytes, why: str) -> None:
        self.state.bad_lines += 1
        shown = raw[:60].decode("ascii", errors="backslashreplace")
        self.state.last_bad = f"{shown!r}: {why}"
        if not self.ansi:
            self._emit(f"bad line #{self.state.bad_lines}: {self.state.last_bad}")

    def _flush_pending(self, force: bool) -> None:
        """Samples wait for the INFO reply (for axis and sensor names) unless none is coming."""
        if not force and self.state.info is None and self._info_sent_at is not None:
            return
        for sample, received in self._pending:
            if self.count is not None and self.state.samples >= self.count:
                break
            prev = self.state.sample
            if prev is not None and sample.seq > prev.seq + 1:
                self.state.seq_gaps += sample.seq - prev.seq - 1
            self.state.sample = sample
            self.state.samples += 1
            if self.log:
                self.log.write(self.state, received)
            if not self.ansi:
                self._emit(plain_sample_line(self.state))
        self._pending.clear()

    # ---- output ----------------------------------------------------------------------------
    def _event(self, text: str) -> None:
        if self.ansi:
            self.state.messages = (self.state.messages + [text])[-3:]
        else:
            self._emit(text)

    def _emit(self, text: str, final: bool = False) -> None:
        if self.ansi and not final:
            return
        self.out.write(text + "\n")
        self.out.flush()

    def _draw(self, force: bool = False) -> None:
        if not self.ansi:
            return
        now = time.monotonic()
        if not force and now - self._last_draw < REDRAW_S:
            return
        self._last_draw = now
        lines = render(self.state, now) + [f"  {m}" for m in self.state.messages]
        buf = io.StringIO()
        if self._drawn:
            buf.write(f"\x1b[{self._drawn}F")  # back to the first line of the last frame
        buf.write("\x1b[J")  # clear it and everything below
        buf.write("\n".join(lines) + "\n")
        self.out.write(buf.getvalue())
        self.out.flush()
        self._drawn = len(lines)
