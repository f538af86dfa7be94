"""`host monitor`: watch a running box (or the HIL's pty) live, and log what it sends.

Why it exists: at the machine, the first questions are "is the right model on this box?", "what
is it correcting right now?" and "is any thermocouple faulted?". The monitor asks INFO, checks
the model hash against the model.json the user has, then shows the corrections, the channel
temperatures and the status flags as they arrive. When a fault flag comes up it asks STATUS and
names the faulted channel (from the box's per-channel fault words) and the axes that hold (from
--model); a faulted channel is shown as such, never as a normal temperature. A box on a factory
floor sends noise and gets unplugged: bad lines are counted and shown, never fatal, silence
longer than two sample periods raises STALE, and a lost port is reopened; when what reappears
at the path cannot identify itself (a pty, an adapter without a serial number), nothing it
sends is shown until its INFO answer names its model. Every fault is kept in a history (what,
since when, cleared when: host.box.history), and the age and STALE keep counting while the
port is gone.

Layout: ``MonitorState`` is what is known, ``Monitor`` reads the port and keeps it current,
and the views only read it: ``render`` (the live lines) in the curses screen
(host.box.screen), ``plain_sample_line`` for a pipe, ``json_sample`` for --json, ``CsvLog``
for --log. A ``LineView`` sees the box's lines themselves, as received, and the serial link
come and go: ``host monitor --mqtt`` passes the fleet gateway's relay (host.fleet.gateway
.BoxRelay), so the broker gets exactly what ``host gateway`` would publish from those lines.

The sign (docs/protocol.md): the box's correction is its prediction of the thermal
displacement, in the sign of the displacement measured in the thermal test (compensated =
measured − correction), so the offset a CNC applies is −correction.
"""

from __future__ import annotations

import csv
import json
import os
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, TextIO

import serial

from contract import protocol
from contract.errors import InputError
from contract.tilt import unit_of, unit_text
from host.box.history import LINK, SAMPLE, FaultEntry, FaultHistory, clock, sample_fault_labels
from host.box.screen import GREY, RED, RESET, Screen

RETRY_S = 1.0
INFO_TIMEOUT_S = 1.0
INFO_ATTEMPTS = 3
REDRAW_S = 0.1
STATUS_EVERY_S = 1.0  # while a fault flag is up, the per-channel fault words are re-read this often
STALE_PERIODS = 2.0  # no line for more than this many expected intervals: STALE

SIGN_NOTE = ("sign: a correction is the box's prediction of the thermal displacement, in the "
             "sign of the displacement measured in the thermal test (compensated = measured − "
             "correction): the offset to apply is −correction")

# flags that mean some channel is faulted: ask STATUS which one
_FAULT_FLAGS = {"HOLD", "RANGE", "OPEN", "TC_FAULT", "AUX_FAULT", "NO_DATA", "IMPLAUSIBLE",
                "BEYOND"}
# the flags a channel's fault word explains, and the fault word's bits each one stands for
_CHANNEL_FLAGS = {"TC_FAULT": {"OVUV", "TCLOW", "TCHIGH", "CJLOW", "CJHIGH", "TCRANGE",
                               "CJRANGE"}, "OPEN": {"OPEN"}, "RANGE": {"RANGE"},
                  "IMPLAUSIBLE": {"IMPLAUSIBLE"}, "BEYOND": {"BEYOND"}}


class MonitorError(InputError):
    """Bad monitor input (unreadable model, a log file with another layout, a port that
    cannot be opened at start)."""


def status_names(status: int) -> list[str]:
    """Names of the bits set in a status word; a bit newer than this contract (a newer box)
    shows as ``bit<n>``, never as an error."""
    named = len(protocol.STATUS_BITS)
    return protocol.status_names(status) + [f"bit{b}" for b in range(named, 16)
                                             if status >> b & 1]


def channel_fault_names(word: int) -> list[str]:
    """Names of a STATUS per-channel fault word's bits (MAX31856 SR, then the box's own)."""
    return [f.name for f in protocol.ChannelFault if word & f.value and f.name]


@dataclass
class MonitorState:
    """Everything the display shows; updated by the reader, rendered by ``render``."""

    port: str
    info: protocol.Info | None = None
    expected_hash: str | None = None
    sample: protocol.Sample | None = None
    status_report: protocol.StatusReport | None = None
    samples: int = 0
    bad_lines: int = 0
    last_bad: str = ""
    seq_gaps: int = 0
    reconnects: int = 0
    withheld: int = 0  # samples not shown because the device had not identified itself
    connected: bool = False
    last_rx: float | None = None  # any valid line
    last_sample_rx: float | None = None
    seq_step: int = 1  # seq advance between the last two samples (RATE n: n)
    stale: bool = False
    messages: list[str] = field(default_factory=list)
    # sensor -> (window_lo, window_hi) codes from model.json (codegen's EXTRAP windows); used
    # only while the box reports that model's hash, to name the channels behind EXTRAP
    windows: dict[str, tuple[int, int]] = field(default_factory=dict)
    # axis -> thermocouples its terms read (from --model): names the axes a fault holds
    axis_inputs: dict[str, list[str]] = field(default_factory=dict)
    history: FaultHistory = field(default_factory=FaultHistory)
    # axis -> the model's promise (model.json metrics.promise, the wording host train and the
    # report use): shown while the box runs that model
    promises: dict[str, str] = field(default_factory=dict)
    period_hint_s: float | None = None  # the last INFO's period: kept while INFO is re-asked
    disconnected_at: float | None = None  # monotonic time the port was lost

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

    @property
    def flags(self) -> list[str]:
        return status_names(self.sample.status) if self.sample is not None else []

    def period_s(self) -> float | None:
        """The box's sample period (INFO), or the last one known while INFO is asked again
        (after a reconnect): the age and STALE keep counting when the box has gone away."""
        if self.info and self.info.period_ms:
            return self.info.period_ms / 1000.0
        return self.period_hint_s

    def faulted_channels(self) -> dict[str, list[str]]:
        """Channel name -> fault names, from the latest STATUS reply, while the current
        sample still raises a fault flag (a cleared fault clears the map)."""
        rep, s = self.status_report, self.sample
        if rep is None or s is None or not (set(self.flags) & _FAULT_FLAGS):
            return {}
        names = self.channel_names(max(len(rep.channel_faults), len(s.temp_codes)))
        return {names[i]: channel_fault_names(w) or [f"0x{w:04X}"]
                for i, w in enumerate(rep.channel_faults) if w}

    def unnamed_channel_faults(self) -> list[str]:
        """Channel-fault flags of the current sample whose channel no STATUS reply has named
        yet (the reply is on its way): every channel is then suspect."""
        named = {f for faults in self.faulted_channels().values() for f in faults}
        return [n for n in self.flags if n in _CHANNEL_FLAGS and not _CHANNEL_FLAGS[n] & named]

    def invalid_channels(self) -> dict[str, str]:
        """Channel name -> why its reading is not a temperature: its faults from STATUS, or,
        while a channel-fault flag is up and STATUS has not named the channel yet, every
        channel ("OPEN?": one of them is open, which one is not known yet)."""
        s = self.sample
        if s is None:
            return {}
        out = {n: "/".join(f) for n, f in self.faulted_channels().items()}
        unnamed = self.unnamed_channel_faults()
        if unnamed:
            for n in self.channel_names(len(s.temp_codes)):
                out.setdefault(n, "/".join(f"{u}?" for u in unnamed))
        return out

    def held_axes(self) -> list[str] | None:
        """Axes that read a faulted channel (so hold), when --model says which axes read
        what and the box runs that model; None when it cannot be told."""
        if "HOLD" not in self.flags:
            return []
        faulted = set(self.faulted_channels())
        if not faulted or not self.axis_inputs or self.hash_ok is not True:
            return None
        return [a for a, inputs in self.axis_inputs.items() if faulted & set(inputs)]

    def zero_seq(self) -> int | None:
        rep = self.status_report
        return getattr(rep, "zero_seq", None) if rep is not None else None

    def beyond_training(self) -> list[str]:
        """Channels of the current sample outside their training window (named only when the
        box runs the model.json the windows came from)."""
        s = self.sample
        if s is None or not self.windows or self.hash_ok is not True:
            return []
        names = self.channel_names(len(s.temp_codes))
        return [n for n, code in zip(names, s.temp_codes, strict=True)
                if n in self.windows and not self.windows[n][0] <= code <= self.windows[n][1]]

    def silence_s(self, now: float) -> float | None:
        return None if self.last_sample_rx is None else now - self.last_sample_rx

    def stale_after_s(self) -> float | None:
        period = self.period_s()
        return None if period is None else STALE_PERIODS * period * max(1, self.seq_step)


def flag_labels(state: MonitorState) -> list[str]:
    """The status flags of the current sample, each named with what it concerns: EXTRAP and
    the channel faults with their channels, HOLD with its axes, REFERENCED with its ZERO (in
    the order of ``state.flags``)."""
    assert state.sample is not None
    names = state.flags
    faulted = state.faulted_channels()
    out: list[str] = []
    for n in names:
        if n == "EXTRAP":
            beyond = state.beyond_training()
            out.append(f"EXTRAP({'+'.join(beyond)})" if beyond else n)
        elif n == "HOLD":
            held = state.held_axes()
            chans = "+".join(faulted)
            out.append(f"HOLD({'+'.join(held)})" if held else
                       f"HOLD(axes reading {chans})" if chans else n)
        elif n in _CHANNEL_FLAGS:
            chans = [c for c, f in faulted.items() if _CHANNEL_FLAGS[n] & set(f)]
            out.append(f"{n}({'+'.join(chans)})" if chans else n)
        elif n == "REFERENCED" and state.zero_seq() is not None:
            out.append(f"REFERENCED(since #{state.zero_seq()})")
        else:
            out.append(n)
    return out


def _flags(state: MonitorState, sep: str) -> str:
    return sep.join(flag_labels(state)) or "ok"


def _hash_line(state: MonitorState) -> str:
    if state.info is None:
        return "model: (no INFO reply yet)"
    info = state.info
    # what matters first: on a narrow terminal the end of the line is what is cut
    text = f"model {info.model_hash}"
    if state.hash_ok is True:
        text += " matches model.json"
    elif state.hash_ok is False:
        text += f", MISMATCH: model.json is {state.expected_hash}"
    return text + (f" (CRC {'OK' if info.crc_ok else 'BAD'}), firmware {info.fw_version}, "
                   f"period {info.period_ms} ms")


def _reference_line(state: MonitorState) -> str:
    if "REFERENCED" in state.flags:
        z = state.zero_seq()
        return ("corrections are the change since ZERO"
                + (f" (reference from sample #{z})" if z is not None else ""))
    return "corrections are absolute (no ZERO reference in force)"


# ---- in service (issue 42): the estimator per axis, from the STATUS line -----------------
REFUSALS_WARN = 2  # readings the gate refused in a row that the view calls out


def service_lines(state: MonitorState, colour: bool = False) -> list[str]:
    """Per axis the box's in-service estimate (the bias MEAS taught it) and the last
    reading's residual (innovation); repeated refusals in red: the model misses by more than
    the gate lets through (or the artifact is dirty), and the estimate stays where it was."""
    svc = getattr(state.status_report, "service", None)
    if not svc:
        return []
    red, reset = (RED, RESET) if colour else ("", "")
    out = []
    for name, a in zip(state.axis_names(len(svc)), svc, strict=True):
        if a is None:
            out.append(f"  estimate   {name:>10}: off (no service block: MEAS refused)")
            continue
        unit = unit_text(name)
        res = "-" if a.innovation_nm is None else f"{a.innovation_nm / 1000.0:+.3f} {unit}"
        line = f"  estimate   {name:>10}: {a.bias_nm / 1000.0:+10.3f} {unit}, last residual {res}"
        if a.refusals >= REFUSALS_WARN:
            line = (f"{red}{line}, {a.refusals} readings REFUSED in a row (beyond the gate: "
                    f"check the artifact, or ZERO){reset}")
        elif a.refusals:
            line += f", {a.refusals} refused"
        out.append(line)
    return out


def render(state: MonitorState, now: float, colour: bool = False) -> list[str]:
    """The live state as lines (the terminal view shows these above the fault history)."""
    grey, red, reset = (GREY, RED, RESET) if colour else ("", "", "")
    if state.connected:
        link = "connected"
    else:
        gone = ("" if state.disconnected_at is None
                else f" for {now - state.disconnected_at:.1f} s")
        link = f"{red}DISCONNECTED{gone}, retrying{reset}"
    lines = [f"host monitor on {state.port}: {link}", _hash_line(state)]
    silence, limit = state.silence_s(now), state.stale_after_s()
    if silence is not None and limit is not None and silence > limit:
        lines.append(f"{red}STALE: no sample for {silence:.1f} s (expected every "
                     f"{limit / STALE_PERIODS:g} s): the values below are old{reset}")
    s = state.sample
    if s is None:
        lines.append("no sample yet")
    else:
        age = "" if silence is None else f", {silence:.1f} s ago"
        lines.append(f"sample #{s.seq}{age}   status {s.status:04X}: {_flags(state, ', ')}")
        lines.append(f"  offset to apply = −correction; {_reference_line(state)}")
        held = set(state.held_axes() or [])
        for name, nm in zip(state.axis_names(len(s.corrections_nm)), s.corrections_nm,
                            strict=True):
            mark = "  (HOLD: last good value)" if name in held else ""
            lines.append(f"  correction {name:>10}: {nm / 1000.0:+10.3f} "
                         f"{unit_text(name)}{mark}")
        lines += service_lines(state, colour)
        if state.hash_ok is True:
            for name in state.axis_names(len(s.corrections_nm)):
                if state.promises.get(name):
                    lines.append(f"  promised   {name:>10}: {state.promises[name]}")
        invalid = state.invalid_channels()
        temps = []
        for name, code in zip(state.channel_names(len(s.temp_codes)), s.temp_codes,
                              strict=True):
            if name in invalid:
                temps.append(f"{grey}{name} {invalid[name]:>9}{reset}")
            else:
                temps.append(f"{name} {code / 128.0:7.2f} °C")
        for i in range(0, len(temps), 4):
            lines.append("  " + "   ".join(temps[i:i + 4]))
    lines.append(f"samples {state.samples}   bad lines {state.bad_lines}   "
                 f"seq gaps {state.seq_gaps}   reconnects {state.reconnects}"
                 + (f"   withheld {state.withheld}" if state.withheld else ""))
    if state.last_bad:
        lines.append(f"  last bad line: {state.last_bad}")
    return lines


def plain_sample_line(state: MonitorState) -> str:
    """One line per sample when the output is not a terminal (logs, pipes, scripts)."""
    s = state.sample
    assert s is not None
    corr = " ".join(f"{n}={nm / 1000.0:+.3f}{unit_of(n)}" for n, nm in
                    zip(state.axis_names(len(s.corrections_nm)), s.corrections_nm, strict=True))
    invalid = state.invalid_channels()
    temps = " ".join(f"{n}=FAULT({invalid[n]})" if n in invalid else
                     f"{n}={c / 128.0:.2f}C" for n, c in
                     zip(state.channel_names(len(s.temp_codes)), s.temp_codes, strict=True))
    flags = _flags(state, ",")
    return (f"seq={s.seq} status={s.status:04X}[{flags}] {corr} {temps} "
            f"bad={state.bad_lines}".replace("  ", " "))


def json_sample(state: MonitorState, received: float) -> dict:
    """One sample as the ``--json`` object: corrections per axis (µm; µrad for a tilt axis,
    named in ``units``), temperatures (°C, null for a faulted channel) per sensor, flags,
    faulted channels and held axes."""
    s = state.sample
    assert s is not None
    faulted = state.faulted_channels()
    invalid = state.invalid_channels()
    names = state.channel_names(len(s.temp_codes))
    return {
        "type": "sample", "seq": s.seq, "status": f"{s.status:04X}", "flags": state.flags,
        "corrections_um": {n: nm / 1000.0 for n, nm in
                           zip(state.axis_names(len(s.corrections_nm)), s.corrections_nm,
                               strict=True)},
        "units": {n: unit_of(n) for n in state.axis_names(len(s.corrections_nm))},
        "temperatures_c": {n: (None if n in invalid else c / 128.0)
                           for n, c in zip(names, s.temp_codes, strict=True)},
        "faulted_channels": faulted, "held_axes": state.held_axes(),
        "beyond_training": state.beyond_training(),
        "referenced": "REFERENCED" in state.flags, "zero_seq": state.zero_seq(),
        "model_hash_ok": state.hash_ok, "host_unix_s": round(received, 3),
    }


class CsvLog:
    """Appends samples as CSV; the header is fixed by the first sample's layout and checked
    against an existing file so two layouts never mix in one log.

    A faulted channel's reading is not a temperature: its cell is left empty (what a run file
    calls a missing value) and the ``faults`` column says why (``T12=OPEN``; ``T05=OPEN?`` for
    every channel while the box has raised OPEN and STATUS has not yet said which one)."""

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
                  + state.channel_names(len(s.temp_codes)) + ["faults", "host_unix_s"])
        if self._fh is None:
            self._open(header)
        elif header != self.header:
            raise MonitorError(f"{self.path}: the box's layout changed ({', '.join(header)}); "
                               "start a new --log file")
        assert self._writer is not None and self._fh is not None
        invalid = state.invalid_channels()
        names = state.channel_names(len(s.temp_codes))
        self._writer.writerow([f"{s.seq * period_s:.6g}", s.seq, f"{s.status:04X}"]
                              + [f"{nm / 1000.0:.3f}" for nm in s.corrections_nm]
                              + ["" if n in invalid else f"{c / 128.0:.4f}"
                                 for n, c in zip(names, s.temp_codes, strict=True)]
                              + [";".join(f"{n}={why}" for n, why in invalid.items()),
                                 f"{received:.3f}"])
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


def device_identity(port: str) -> str | None:
    """What the device at ``port`` says it is without being asked: a USB adapter's serial
    number (vendor:product:serial). None for a pty, a URL or an adapter without a serial
    number: such a device can only be known by its INFO answer."""
    if "://" in port:
        return None
    try:
        from serial.tools import list_ports

        real = os.path.realpath(port)
        for p in list_ports.comports():
            if os.path.realpath(p.device) == real and p.serial_number:
                return f"{p.vid or 0:04x}:{p.pid or 0:04x}:{p.serial_number}"
    except (OSError, ImportError):
        return None
    return None


class LineView(Protocol):
    """A view fed the box's lines as received (every one, good or bad) and the serial link's
    coming and going, with wall-clock times; ``start`` before the first, ``stop`` at the end.
    host.fleet.gateway.BoxRelay is one (the MQTT publisher of ``host monitor --mqtt``)."""

    def start(self) -> None: ...

    def line(self, raw: bytes, now: float) -> object: ...

    def connected(self, port: str, now: float) -> None: ...

    def lost(self, why: str, now: float) -> None: ...

    def stop(self) -> None: ...


class Monitor:
    """Reads lines from the box, keeps ``state`` current, shows it and logs samples.

    ``count``/``duration`` stop it for scripts; ``screen`` shows the full-screen terminal view
    (curses, host.box.screen; default: when ``out`` is a terminal), else one plain line per
    sample and per event; ``json_lines`` prints one JSON object per sample and per event
    instead. Whatever the output, the state (``state``, with its fault history) is the same:
    another view (a broker, say) reads ``state`` and the events, and needs nothing else.
    """

    def __init__(self, port: str, baud: int = 115200, expected_hash: str | None = None,
                 windows: dict[str, tuple[int, int]] | None = None,
                 log: str | Path | None = None, count: int | None = None,
                 duration: float | None = None, out: TextIO | None = None,
                 screen: bool | None = None, retry_s: float = RETRY_S,
                 opener: Callable[[str, int], serial.SerialBase] = open_port,
                 axis_inputs: Mapping[str, Sequence[str]] | None = None,
                 json_lines: bool = False,
                 identify: Callable[[str], str | None] = device_identity,
                 promises: Mapping[str, str] | None = None,
                 views: Sequence[LineView] = ()) -> None:
        self.port_name = port
        self.views = list(views)
        self._out_lock = threading.Lock()  # note() may come from another thread
        self.baud = baud
        self.count = count
        self.duration = duration
        self.out = sys.stdout if out is None else out
        self.json = json_lines
        self.screen = False if json_lines else (self.out.isatty() if screen is None
                                                 else screen)
        self._screen: Screen | None = None
        self.retry_s = retry_s
        self.opener = opener
        self.identify = identify
        self.state = MonitorState(port, expected_hash=expected_hash, windows=dict(windows or {}),
                                  axis_inputs={a: list(v) for a, v in (axis_inputs or {}).items()},
                                  promises=dict(promises or {}))
        self.log = CsvLog(log) if log else None
        self._port: serial.SerialBase | None = None
        self._buf = bytearray()
        self._last_draw = 0.0
        self._info_sent_at: float | None = None
        self._info_attempts = 0
        self._next_retry = 0.0
        self._pending: list[tuple[protocol.Sample, float]] = []
        self._identity: str | None = None
        self._previous_hash: str | None = None
        self._must_identify = False  # after a reconnect to a device that cannot say what it is
        self._status_sent_at: float | None = None
        self._status_for: frozenset[str] = frozenset()

    # ---- life cycle ------------------------------------------------------------------------
    def run(self) -> int:
        """Monitor until count/duration is reached (or Ctrl-C, or q on the screen); 1 if the
        model check failed."""
        start = time.monotonic()
        try:
            self._port = self.opener(self.port_name, self.baud)
        except (OSError, serial.SerialException) as exc:
            raise MonitorError(f"{self.port_name}: cannot open serial port: {exc}") from None
        self._identity = self.identify(self.port_name)
        started: list[LineView] = []
        try:
            for view in self.views:
                view.start()
                started.append(view)
        except BaseException:
            for view in started:
                view.stop()
            self._port.close()
            raise
        if self.screen:
            self._screen = Screen()
            self._screen.start()
        self._connected()
        try:
            while not self._done(start):
                if self._port is None:
                    self._reconnect(start)
                else:
                    try:
                        self._poll()
                    except (OSError, serial.SerialException) as exc:
                        self._lost(exc)
                # also while the port is gone: the age and STALE keep counting on screen
                self._check_stale(time.monotonic())
                self._draw()
                if self._screen is not None and self._screen.key() == "quit":
                    break
        except KeyboardInterrupt:
            pass
        finally:
            self._flush_pending(force=True)
            if self._screen is not None:
                self._screen.stop()
                self._screen = None
                # the last frame stays readable in the terminal after the screen is gone
                now = time.monotonic()
                self._emit("\n".join([*render(self.state, now),
                                      "fault history (newest first):",
                                      *(f"  {ln}" for ln in self.state.history.lines(
                                          time.time())), ""]), final=True)
            if self._port is not None:
                self._port.close()
            if self.log:
                self.log.close()
            for view in self.views:
                view.stop()
        st = self.state
        text = (f"monitor: {st.samples} samples, {st.bad_lines} bad lines, {st.seq_gaps} seq "
                f"gaps, {st.reconnects} reconnects"
                + (f", {st.withheld} withheld from an unidentified device" if st.withheld
                   else ""))
        faults = len(st.history.entries)
        if faults:
            text += f", {faults} fault{'s' if faults != 1 else ''} in the history"
        if self.json:
            self._json({"type": "summary", "samples": st.samples, "bad_lines": st.bad_lines,
                        "seq_gaps": st.seq_gaps, "reconnects": st.reconnects,
                        "withheld": st.withheld, "model_hash_ok": st.hash_ok,
                        "faults": [e.as_json() for e in st.history.entries]})
        else:
            self._emit(text, final=True)
        if st.hash_ok is False or (st.info is not None and not st.info.crc_ok):
            return 1
        return 0

    def _done(self, start: float) -> bool:
        if self.count is not None and self.state.samples >= self.count:
            return True
        return self.duration is not None and time.monotonic() - start >= self.duration

    def _connected(self) -> None:
        self.state.connected = True
        self.state.disconnected_at = None
        self._history(self.state.history.close(LINK, "DISCONNECTED", time.time()))
        self._buf.clear()
        self._info_attempts = 0
        self._ask_info()
        self._event(f"connected to {self.port_name}", kind="connected")
        for view in self.views:
            view.connected(self.port_name, time.time())

    def _lost(self, exc: BaseException) -> None:
        self._event(f"connection lost ({exc}); retrying every {self.retry_s:g} s", kind="lost")
        for view in self.views:
            view.lost(str(exc), time.time())
        try:
            if self._port is not None:
                self._port.close()
        except (OSError, serial.SerialException):
            pass
        self._port = None
        self.state.connected = False
        self.state.disconnected_at = time.monotonic()
        self._history(self.state.history.open(LINK, "DISCONNECTED", "DISCONNECTED (port lost)",
                                              time.time()))
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
        if self.state.info is not None:
            self._previous_hash = self.state.info.model_hash
        self.state.info = None  # the box may have been swapped or reflashed: ask again
        self.state.status_report = None
        identity = self.identify(self.port_name)
        # a device that cannot say what it is (a pty, an adapter without a serial number), or
        # another adapter: nothing it sends is shown until its INFO answer names its model
        self._must_identify = identity is None or identity != self._identity
        self._identity = identity
        self._connected()
        if self._must_identify:
            self._event("the device now at this path cannot identify itself: its model hash "
                        "is checked (INFO) before anything it sends is shown", kind="identify")

    # ---- reading ---------------------------------------------------------------------------
    def _ask_info(self) -> None:
        assert self._port is not None
        self._port.write(protocol.encode_command("INFO"))
        self._port.flush()
        self._info_sent_at = time.monotonic()
        self._info_attempts += 1

    def _ask_status(self, now: float) -> None:
        if self._port is None:
            return
        self._port.write(protocol.encode_command("STATUS"))
        self._port.flush()
        self._status_sent_at = now

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
                if self._must_identify:
                    self._event("no INFO reply from the device now at this path: its lines are "
                                "not shown (it is not known to be the box)", kind="unidentified")
                else:
                    self._event("no INFO reply: showing samples without names", kind="no_info")
                self._flush_pending(force=True)
        if not data:
            return
        self._buf += data
        while b"\n" in self._buf:
            line, _, rest = bytes(self._buf).partition(b"\n")
            self._buf = bytearray(rest)
            self._handle(line.rstrip(b"\r"), now)
        if len(self._buf) > 1024:  # noise without newlines: drop it, count it
            for view in self.views:
                view.line(bytes(self._buf[:200]), time.time())
            self._bad(bytes(self._buf[:60]), "no end of line in 1024 bytes")
            self._buf.clear()

    def _handle(self, raw: bytes, now: float) -> None:
        if not raw.strip():
            return
        for view in self.views:
            view.line(raw, time.time())
        try:
            message = protocol.decode(raw)
        except protocol.ProtocolError as exc:
            self._bad(raw, str(exc))
            return
        self.state.last_rx = now
        if isinstance(message, protocol.Info):
            self._got_info(message)
        elif isinstance(message, protocol.StatusReport):
            self.state.status_report = message
        elif isinstance(message, protocol.Sample):
            if self.state.stale:
                silence = self.state.silence_s(now)
                self.state.stale = False
                self._event(f"samples resumed after {silence or 0:.1f} s", kind="resumed")
                self._history(self.state.history.close(LINK, "STALE", time.time(),
                                                       message.seq))
            self.state.last_sample_rx = now
            self._pending.append((message, time.time()))
            self._want_status(message, now)
            self._flush_pending(force=False)

    def _got_info(self, info: protocol.Info) -> None:
        st = self.state
        st.info = info
        if info.period_ms:
            st.period_hint_s = info.period_ms / 1000.0
        self._info_sent_at = None
        self._event(_hash_line(st), kind="info")
        if self._previous_hash is not None and info.model_hash != self._previous_hash:
            self._event(f"the device now at this path runs model {info.model_hash}, not "
                        f"{self._previous_hash} as before the connection was lost",
                        kind="model_changed")
        if self._must_identify and st.expected_hash is not None and st.hash_ok is False:
            self._event("its model hash does not match model.json: its samples are not shown",
                        kind="unidentified")
            self._pending.clear()
            return
        self._must_identify = False
        if st.reconnects == 0 or self._previous_hash is None:
            self._event(SIGN_NOTE, kind="sign")
        self._flush_pending(force=True)

    def _want_status(self, sample: protocol.Sample, now: float) -> None:
        """Ask STATUS (the per-channel fault words, the ZERO reference) when the fault or
        reference flags change, and again every STATUS_EVERY_S while a fault flag is up."""
        flags = frozenset(status_names(sample.status)) & (_FAULT_FLAGS | {"REFERENCED"})
        if not flags:
            self._status_for = flags
            return
        changed = flags != self._status_for
        due = self._status_sent_at is None or now - self._status_sent_at >= STATUS_EVERY_S
        if changed or (due and flags & _FAULT_FLAGS):
            self._status_for = flags
            self._ask_status(now)

    def _check_stale(self, now: float) -> None:
        st = self.state
        silence, limit = st.silence_s(now), st.stale_after_s()
        if st.stale or silence is None or limit is None or silence <= limit:
            return
        st.stale = True
        self._event(f"STALE: no sample for {silence:.1f} s (expected every "
                    f"{limit / STALE_PERIODS:g} s); the last values shown are old", kind="stale")
        last = st.sample.seq if st.sample is not None else None
        self._history(st.history.open(LINK, "STALE", "STALE (no samples)",
                                      time.time() - silence, last))

    def _bad(self, raw: bytes, why: str) -> None:
        self.state.bad_lines += 1
        shown = raw[:60].decode("ascii", errors="backslashreplace")
        self.state.last_bad = f"{shown!r}: {why}"
        if self.json:
            self._json({"type": "bad_line", "n": self.state.bad_lines, "line": shown,
                        "why": why})
        elif not self.screen:
            self._emit(f"bad line #{self.state.bad_lines}: {self.state.last_bad}")

    def _flush_pending(self, force: bool) -> None:
        """Samples wait for the INFO reply (for axis and sensor names) unless none is coming;
        from a device that must identify itself first, they are withheld until it has."""
        if not force and self.state.info is None and self._info_sent_at is not None:
            return
        if self._must_identify:
            if self.state.info is None and self._info_sent_at is None:
                self.state.withheld += len(self._pending)
                self._pending.clear()
            return
        for sample, received in self._pending:
            if self.count is not None and self.state.samples >= self.count:
                break
            prev = self.state.sample
            if prev is not None and sample.seq > prev.seq:
                self.state.seq_step = min(sample.seq - prev.seq, 3600)
            if prev is not None and sample.seq > prev.seq + 1:
                self.state.seq_gaps += sample.seq - prev.seq - 1
            self.state.sample = sample
            self.state.samples += 1
            st = self.state
            self._history(st.history.update(SAMPLE, sample_fault_labels(
                st.flags, flag_labels(st)), received, sample.seq))
            if self.log:
                self.log.write(self.state, received)
            if self.json:
                self._json(json_sample(self.state, received))
            elif not self.screen:
                self._emit(plain_sample_line(self.state))
        self._pending.clear()

    # ---- output ----------------------------------------------------------------------------
    def _history(self, changes: list[tuple[str, FaultEntry]]) -> None:
        """Announce the fault history's changes as events (a line, a JSON object; on the
        screen the history itself shows them)."""
        for what, e in changes:
            seq = f" at #{e.since_seq}" if e.since_seq is not None else ""
            if what == "fault":
                text = f"fault: {e.label} since {clock(e.since)}{seq}"
            else:
                assert e.cleared is not None
                end = f" at #{e.cleared_seq}" if e.cleared_seq is not None else ""
                text = (f"cleared: {e.label} at {clock(e.cleared)}{end}, after "
                        f"{e.cleared - e.since:.1f} s (since {clock(e.since)}{seq})")
            if self.json:
                self._json({"type": "fault" if what == "fault" else "fault_cleared",
                            **e.as_json()})
            elif not self.screen:
                self._emit(text)

    def note(self, text: str, kind: str = "note") -> None:
        """An event from elsewhere (a view's own news, from any thread), shown like the
        monitor's own events."""
        self._event(text, kind)

    def _event(self, text: str, kind: str = "event") -> None:
        if self.json:
            self._json({"type": "event", "event": kind, "message": text,
                        "host_unix_s": round(time.time(), 3)})
        elif self.screen:
            with self._out_lock:
                self.state.messages = (self.state.messages
                                       + [f"{clock(time.time())} {text}"])[-20:]
        else:
            self._emit(text)

    def _json(self, obj: dict) -> None:
        with self._out_lock:
            self.out.write(json.dumps(obj, ensure_ascii=False) + "\n")
            self.out.flush()

    def _emit(self, text: str, final: bool = False) -> None:
        if self._screen is not None or (self.screen and not final):
            return
        with self._out_lock:
            self.out.write(text + "\n")
            self.out.flush()

    def _draw(self, force: bool = False) -> None:
        if self._screen is None:
            return
        now = time.monotonic()
        if not force and now - self._last_draw < REDRAW_S:
            return
        self._last_draw = now
        self._screen.draw(render(self.state, now, colour=True),
                          self.state.history.lines(time.time()), self.state.messages)
