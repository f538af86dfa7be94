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

import json
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TextIO

import serial

from thermal_comp.contract import protocol
from thermal_comp.host.box.csvlog import CsvLog
from thermal_comp.host.box.history import LINK, SAMPLE, FaultEntry, clock, sample_fault_labels
from thermal_comp.host.box.link import LineView, device_identity, open_port
from thermal_comp.host.box.screen import Screen
from thermal_comp.host.box.state import (
    FAULT_FLAGS,
    SIGN_NOTE,
    STALE_PERIODS,
    MonitorError,
    MonitorState,
    flag_labels,
    hash_line,
    status_names,
)
from thermal_comp.host.box.views import json_sample, plain_sample_line, render

RETRY_S = 1.0
INFO_TIMEOUT_S = 1.0
INFO_ATTEMPTS = 3
REDRAW_S = 0.1
STATUS_EVERY_S = 1.0  # while a fault flag is up, the per-channel fault words are re-read this often


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
        self._open()
        if self.screen:
            self._screen = Screen()
            self._screen.start()
        self._connected()
        try:
            self._watch(start)
        except KeyboardInterrupt:
            pass
        finally:
            self._close()
        return self._summary()

    def _open(self) -> None:
        """The port opened and identified, every view started (none left running, the port
        closed, when one fails to start)."""
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

    def _watch(self, start: float) -> None:
        """Read, reconnect and draw until done or q on the screen."""
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

    def _close(self) -> None:
        """What is pending written, the screen's last frame left in the terminal, the port,
        the log and the views closed."""
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

    def _summary(self) -> int:
        """The closing line (or JSON summary); 1 if the model check failed, else 0."""
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
        self._event(hash_line(st), kind="info")
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
        flags = frozenset(status_names(sample.status)) & (FAULT_FLAGS | {"REFERENCED"})
        if not flags:
            self._status_for = flags
            return
        changed = flags != self._status_for
        due = self._status_sent_at is None or now - self._status_sent_at >= STATUS_EVERY_S
        if changed or (due and flags & FAULT_FLAGS):
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
