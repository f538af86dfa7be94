#!/usr/bin/python3
"""thermalcomp: a LinuxCNC userspace HAL component that puts the box's corrections on external
offsets (docs/linuxcnc.md).

It reads the box's serial stream (docs/protocol.md) from a serial port (/dev/ttyUSB0 on a real
machine, a pseudo-terminal in the tests), checks every line's CRC and sequence number with the
project's own decoder, maps box axes to LinuxCNC axes with the sign and count size of a small
config file (cnc/config/thermalcomp.conf) and drives ``axis.L.eoffset-counts/-scale/-enable/
-clear``. Rules, in the order they apply to each axis:

- **hold**: while the box reports a fault (MODEL_BAD, HOLD, NO_DATA, IMPLAUSIBLE), while the
  stream is stale (no sample line for ``stale_periods`` sample periods) and on a line that
  fails its CRC or does not decode, every axis keeps the offset it has.
- **never jump**: the offset moves towards the box's value by at most ``slew_nm_per_s`` times
  the sample period per sample line (the box's own walk-back rate by default), so resuming
  after a hold, or following a box that restarted, is a walk, not a step. While the box
  tracks normally it moves far less than that per sample and the offset equals its value.
- **machine off**: LinuxCNC drops the external offset (and its ``eoffset-request``) when the
  machine goes off but keeps the counts pin, because it reads counts as a change; when the
  machine is on and homed again the component resynchronises: it adds (wanted −
  round(request / scale)) to its counts, so the offset lands on the box's value, not on the
  value before plus the change. The same resync runs after ``enable`` comes back (while
  ``enable`` is false it asserts ``eoffset-clear``: LinuxCNC ramps the offset to 0).
- **box restart** (``seq`` goes back): the box walks from 0 at its slew limit (SLEW); the
  component holds until the box tracks again, then walks to it.
- ``zero`` (rising edge, e.g. from the touch-off macro) sends the box ``ZERO``: from the next
  sample the box outputs the change since then; that first value is a new datum and
  is applied without the walk limit (LinuxCNC still ramps it at OFFSET_AV_RATIO).

Runs under Debian's /usr/bin/python3 (where LinuxCNC's ``hal`` module lives); needs only the
standard library and the project's stdlib-only wire-protocol decoder, found next to this file
(the repository root, or a copy of ``cnc/`` and the decoder's package side by side).
"""

from __future__ import annotations

import argparse
import configparser
import math
import os
import signal
import sys
import termios
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from contract import protocol  # noqa: E402  (stdlib only: docs/architecture.md, floor 0)
from contract.tilt import unit_of  # noqa: E402

NAME = "thermalcomp"
MODEL_BAD, HOLD, SLEW, NO_DATA, EXTRAP = 1 << 0, 1 << 1, 1 << 2, 1 << 9, 1 << 10
REFERENCED, IMPLAUSIBLE = 1 << 11, 1 << 12
HOLD_BITS = MODEL_BAD | HOLD | NO_DATA | IMPLAUSIBLE  # the box says: do not trust this sample
UNITS_MM = {"mm": 1.0, "inch": 25.4}
SEQ_MOD = 1 << 32


class ConfigError(ValueError):
    """The component's config file is missing or wrong (names the file, section and key)."""


@dataclass
class AxisMap:
    """One LinuxCNC axis driven by one box axis."""

    letter: str  # LinuxCNC axis letter, lower case (pin names axis.<letter>.eoffset-*)
    box_axis: str  # name in the box's INFO axis list (the model's target, e.g. dz_um)
    sign: int  # +1: LinuxCNC offset = +correction; -1: offset = -correction
    nm_per_count: float  # size of one eoffset count in nanometres
    index: int | None = None  # position in the box's sample line (from INFO)
    want: int = 0  # offset the component wants, in counts
    sent: int = 0  # the offset LinuxCNC has been told (counts) since the last resync
    seen: bool = False  # a value from the box has been applied since start
    box_nm: int = 0  # the box's last correction for this axis


@dataclass
class Config:
    port: str
    baud: int = 115200
    stale_periods: float = 3.0
    period_s: float | None = None  # None: the box's INFO period
    slew_nm_per_s: float = 1000.0
    units_mm: float = 1.0  # machine units in mm (LINEAR_UNITS)
    settle_s: float = 0.05  # wait after machine-on/enable before reading eoffset-request
    poll_s: float = 0.002
    axes: list[AxisMap] = field(default_factory=list)


def load_config(path: str | Path) -> Config:
    """Read the component's config file (INI syntax, see cnc/config/thermalcomp.conf)."""
    path = Path(path)
    parser = configparser.ConfigParser(inline_comment_prefixes=("#", ";"))
    if not parser.read(path):
        raise ConfigError(f"{path}: component config not found or unreadable")

    def get(section: str, key: str, kind: type, default: object = None) -> object:
        if not parser.has_option(section, key):
            if default is None:
                raise ConfigError(f"{path}: [{section}] needs '{key}'")
            return default
        text = parser.get(section, key)
        try:
            return kind(text)
        except ValueError:
            raise ConfigError(f"{path}: [{section}] {key} = {text!r} is not a valid "
                              f"{kind.__name__}") from None

    if not parser.has_section("box"):
        raise ConfigError(f"{path}: no [box] section (port, stale_periods, ...)")
    units = str(get("machine", "units", str, "mm")) if parser.has_section("machine") else "mm"
    if units not in UNITS_MM:
        raise ConfigError(f"{path}: [machine] units = {units!r}: mm or inch")
    period = get("box", "period_s", float, -1.0)
    cfg = Config(port=str(get("box", "port", str)), baud=int(get("box", "baud", int, 115200)),
                 stale_periods=float(get("box", "stale_periods", float, 3.0)),
                 period_s=None if period == -1.0 else float(period),
                 slew_nm_per_s=float(get("box", "slew_nm_per_s", float, 1000.0)),
                 units_mm=UNITS_MM[units],
                 settle_s=float(get("box", "settle_s", float, 0.05)),
                 poll_s=float(get("box", "poll_s", float, 0.002)))
    for name, value, lo in (("stale_periods", cfg.stale_periods, 1.0),
                            ("slew_nm_per_s", cfg.slew_nm_per_s, 1e-9),
                            ("poll_s", cfg.poll_s, 1e-4)):
        if not (math.isfinite(value) and value >= lo):
            raise ConfigError(f"{path}: [box] {name} = {value:g} must be at least {lo:g}")
    if cfg.period_s is not None and not cfg.period_s > 0:
        raise ConfigError(f"{path}: [box] period_s = {cfg.period_s:g} must be positive")
    for section in parser.sections():
        if not section.startswith("axis."):
            continue
        letter = section[5:].lower()
        if letter not in "xyzabcuvw" or len(letter) != 1:
            raise ConfigError(f"{path}: [{section}]: the axis letter must be one of XYZABCUVW")
        sign_text = str(get(section, "sign", str)).strip()
        if sign_text not in ("+1", "1", "+", "-1", "-"):
            raise ConfigError(f"{path}: [{section}] sign = {sign_text!r}: +1 or -1")
        nm = float(get(section, "nm_per_count", float, 1.0))
        if not (math.isfinite(nm) and nm > 0):
            raise ConfigError(f"{path}: [{section}] nm_per_count = {nm:g} must be positive")
        box_axis = str(get(section, "box_axis", str))
        if unit_of(box_axis) != "um":
            raise ConfigError(f"{path}: [{section}] box_axis = {box_axis}: a tilt axis (urad) "
                              "is not a linear offset; only axes in um drive external offsets")
        cfg.axes.append(AxisMap(letter, box_axis,
                                -1 if sign_text.startswith("-") else 1, nm))
    if not cfg.axes:
        raise ConfigError(f"{path}: no [axis.<letter>] section: nothing to drive")
    letters = [a.letter for a in cfg.axes]
    if len(set(letters)) != len(letters):
        raise ConfigError(f"{path}: an axis letter appears twice ({', '.join(letters)})")
    return cfg


class Port:
    """The box's serial port, opened raw with the standard library (no pyserial needed)."""

    def __init__(self, path: str, baud: int) -> None:
        self.path, self.baud = path, baud
        self.fd: int | None = None
        self.buf = bytearray()
        self.synced = False  # the bytes before the first newline after opening are dropped

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
        self.fd, self.buf, self.synced = fd, bytearray(), False
        return True

    def close(self) -> None:
        if self.fd is not None:
            try:
                os.close(self.fd)
            except OSError:
                pass
        self.fd = None

    def read_lines(self) -> list[bytes] | None:
        """Complete lines received so far (without CR LF); None when the port went away."""
        assert self.fd is not None
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return []
        except OSError:
            return None  # EIO: the other side (box, USB adapter) is gone
        if not data:
            return None
        self.buf += data
        *complete, rest = bytes(self.buf).split(b"\n")
        self.buf = bytearray(rest)
        if not self.synced and complete:
            complete, self.synced = complete[1:], True
        return [line.rstrip(b"\r") for line in complete]

    def write(self, data: bytes) -> bool:
        if self.fd is None:
            return False
        try:
            os.write(self.fd, data)
            return True
        except OSError:
            return False


class Compensator:
    """The component's logic, without HAL: what the pins should say after each event."""

    def __init__(self, cfg: Config, log=None) -> None:
        self.cfg = cfg
        self.log = log or (lambda msg: print(f"{NAME}: {msg}", file=sys.stderr, flush=True))
        self.info: protocol.Info | None = None
        self.last_seq: int | None = None
        self.last_line_t: float | None = None
        self.status = 0
        self.bad_lines = 0
        self.lost_lines = 0
        self.restarts = 0
        self.holds = 0  # sample lines on which the offsets were held
        self.rebooted = False  # the box restarted and is still walking from 0 (SLEW)
        self.rezero = False  # ZERO acknowledged: the next value is a new datum, not a move
        self.zero_acks = 0
        self.zero_seq = -1
        self.stale = False
        self.fault = False
        self.walking = False

    def period_s(self) -> float | None:
        """The sample period the stale check counts in (wall-clock seconds)."""
        if self.cfg.period_s is not None:
            return self.cfg.period_s
        return self.info.period_ms / 1000.0 if self.info is not None else None

    def take_info(self, info: protocol.Info) -> None:
        missing = [a.box_axis for a in self.cfg.axes if a.box_axis not in info.axes]
        if missing:
            self.log(f"the box's model has axes {', '.join(info.axes) or '(none)'}; the config "
                     f"asks for {', '.join(missing)}: those LinuxCNC axes hold")
        for a in self.cfg.axes:
            a.index = info.axes.index(a.box_axis) if a.box_axis in info.axes else None
        if self.info is None or info != self.info:
            self.log(f"box {info.fw_version}, model {info.model_hash} (CRC "
                     f"{'OK' if info.crc_ok else 'BAD'}), {info.period_ms} ms, axes "
                     f"{';'.join(info.axes)}")
        self.info = info

    def take_sample(self, s: protocol.Sample, now: float) -> None:
        if self.last_seq is not None:
            gap = (s.seq - self.last_seq) % SEQ_MOD
            if gap == 0 or gap >= SEQ_MOD // 2:
                self.restarts += 1
                self.rebooted = True
                self.log(f"sequence went from {self.last_seq} to {s.seq}: the box restarted; "
                         "holding until it has walked back from 0")
            elif gap > 1:
                self.lost_lines += gap - 1
                self.log(f"{gap - 1} sample line(s) lost before seq {s.seq}")
        self.last_seq, self.last_line_t, self.status = s.seq, now, s.status
        self.stale = False
        self.fault = bool(s.status & HOLD_BITS)
        if self.rebooted and not s.status & SLEW:
            self.rebooted = False  # the box tracks again: walk to it from the held offset
        if self.fault or self.info is None or self.rebooted:
            # (a restarted box walks from 0 at its slew limit: following it would pull the
            # axis towards 0 and back)
            self.holds += 1
            return
        # the walk limit is per sample period of the box (its INFO), whatever the wall clock
        step_nm = self.cfg.slew_nm_per_s * self.info.period_ms / 1000.0
        self.walking = False
        datum, self.rezero = self.rezero, False
        for a in self.cfg.axes:
            if a.index is None or a.index >= len(s.corrections_nm):
                continue
            a.box_nm = s.corrections_nm[a.index]
            target = round(a.sign * a.box_nm / a.nm_per_count)
            # after ZERO the value changes datum (to ~0) at once: the operator touches off
            # once the offset is 0 (LinuxCNC ramps it at OFFSET_AV_RATIO), docs/linuxcnc.md
            step = abs(target - a.want) if datum else max(1, math.floor(step_nm / a.nm_per_count))
            delta = max(-step, min(step, target - a.want))
            a.want += delta
            a.seen = True
            if a.want != target:
                self.walking = True

    def zeroed(self, seq: int) -> None:
        """The box acknowledged ZERO (``$OK,ZERO,<seq>``): the next value is a new datum."""
        self.zero_acks += 1
        self.zero_seq = seq
        self.rezero = True
        self.log(f"box zeroed at seq {seq}")

    def bad_line(self, raw: bytes, err: Exception) -> None:
        self.bad_lines += 1
        self.holds += 1 if raw.startswith(b"$C,") else 0
        if self.bad_lines <= 10 or self.bad_lines % 100 == 0:
            self.log(f"bad line #{self.bad_lines} (offsets held): {err}")

    def check_stale(self, now: float) -> None:
        period = self.period_s()
        if period is None or self.last_line_t is None:
            return
        stale = now - self.last_line_t > self.cfg.stale_periods * period
        if stale and not self.stale:
            self.log(f"no sample line for {now - self.last_line_t:.3g} s "
                     f"({self.cfg.stale_periods:g} periods): stale, offsets held")
        self.stale = stale

    def age_s(self, now: float) -> float:
        return now - self.last_line_t if self.last_line_t is not None else -1.0


class HalDriver:
    """The HAL side: pins, the LinuxCNC counts bookkeeping, machine-off resync."""

    def __init__(self, cfg: Config, comp: Compensator, name: str = NAME) -> None:
        import hal

        self.hal, self.cfg, self.comp = hal, cfg, comp
        h = self.h = hal.component(name)
        for pin, kind, direction in (
                ("enable", hal.HAL_BIT, hal.HAL_IN), ("machine-on", hal.HAL_BIT, hal.HAL_IN),
                ("homed", hal.HAL_BIT, hal.HAL_IN), ("zero", hal.HAL_BIT, hal.HAL_IN),
                ("connected", hal.HAL_BIT, hal.HAL_OUT), ("active", hal.HAL_BIT, hal.HAL_OUT),
                ("fault", hal.HAL_BIT, hal.HAL_OUT), ("holding", hal.HAL_BIT, hal.HAL_OUT),
                ("walking", hal.HAL_BIT, hal.HAL_OUT), ("stale", hal.HAL_BIT, hal.HAL_OUT),
                ("extrapolating", hal.HAL_BIT, hal.HAL_OUT),
                ("referenced", hal.HAL_BIT, hal.HAL_OUT), ("age-s", hal.HAL_FLOAT, hal.HAL_OUT),
                ("status", hal.HAL_S32, hal.HAL_OUT), ("seq", hal.HAL_S32, hal.HAL_OUT),
                ("bad-lines", hal.HAL_S32, hal.HAL_OUT), ("lost-lines", hal.HAL_S32, hal.HAL_OUT),
                ("holds", hal.HAL_S32, hal.HAL_OUT), ("restarts", hal.HAL_S32, hal.HAL_OUT),
                ("zero-acks", hal.HAL_S32, hal.HAL_OUT), ("zero-seq", hal.HAL_S32, hal.HAL_OUT)):
            h.newpin(pin, kind, direction)
        for a in cfg.axes:
            p = a.letter
            h.newpin(f"{p}.counts", hal.HAL_S32, hal.HAL_OUT)
            h.newpin(f"{p}.scale", hal.HAL_FLOAT, hal.HAL_OUT)
            h.newpin(f"{p}.eoffset-enable", hal.HAL_BIT, hal.HAL_OUT)
            h.newpin(f"{p}.clear", hal.HAL_BIT, hal.HAL_OUT)
            h.newpin(f"{p}.request", hal.HAL_FLOAT, hal.HAL_IN)
            h.newpin(f"{p}.offset", hal.HAL_FLOAT, hal.HAL_OUT)
            h.newpin(f"{p}.correction-nm", hal.HAL_S32, hal.HAL_OUT)
            h[f"{p}.scale"] = self.scale(a)
            h[f"{p}.eoffset-enable"] = True
        h["seq"], h["zero-seq"], h["age-s"] = -1, -1, -1.0
        self.live_since: float | None = None
        self.last_write = 0.0
        self.need_sync = True
        self.zero_was = False
        h.ready()

    def scale(self, a: AxisMap) -> float:
        """eoffset-scale: machine units per count."""
        return a.nm_per_count * 1e-6 / self.cfg.units_mm

    def update(self, now: float, port: Port) -> None:
        h, comp = self.h, self.comp
        live = bool(h["machine-on"]) and bool(h["homed"])
        enabled = bool(h["enable"])
        if not live or not enabled:
            # Machine off: LinuxCNC ignores counts and drops the offset at the next machine-on.
            # Disabled: eoffset-clear ramps it to 0. Either way: resync when it comes back.
            self.live_since, self.need_sync = None, True
        elif self.live_since is None:
            self.live_since = now
        for a in self.cfg.axes:
            h[f"{a.letter}.clear"] = live and not enabled
        if self.live_since is not None and now - self.live_since >= self.cfg.settle_s:
            for a in self.cfg.axes:
                request = round(h[f"{a.letter}.request"] / self.scale(a))
                if self.need_sync:
                    # counts are taken as a change: make request equal what we want
                    h[f"{a.letter}.counts"] = _s32(h[f"{a.letter}.counts"] + a.want - request)
                    a.sent = a.want
                elif a.want != a.sent:
                    h[f"{a.letter}.counts"] = _s32(h[f"{a.letter}.counts"] + a.want - a.sent)
                    a.sent = a.want
                    self.last_write = now
                elif now - self.last_write > self.cfg.settle_s and request != a.sent:
                    # LinuxCNC lost a change (it ignores counts in some states): put it back
                    comp.log(f"axis {a.letter.upper()}: eoffset-request is {request} counts, "
                             f"expected {a.sent}: resynchronising")
                    h[f"{a.letter}.counts"] = _s32(h[f"{a.letter}.counts"] + a.sent - request)
                    self.last_write = now
            if self.need_sync:
                self.last_write, self.need_sync = now, False
        zero = bool(h["zero"])
        if zero and not self.zero_was:
            comp.log("zero: sending ZERO" if port.write(b"ZERO\r\n")
                     else "zero: box not connected, ZERO not sent")
        self.zero_was = zero
        comp.check_stale(now)
        status = comp.status
        h["connected"] = port.fd is not None and comp.info is not None
        h["active"] = self.live_since is not None and not self.need_sync and enabled
        h["fault"] = comp.fault
        h["stale"] = comp.stale
        h["holding"] = comp.fault or comp.stale or comp.rebooted or comp.info is None
        h["walking"] = comp.walking
        h["extrapolating"] = bool(status & EXTRAP)
        h["referenced"] = bool(status & REFERENCED)
        h["status"] = status
        h["age-s"] = comp.age_s(now)
        h["seq"] = _s32(comp.last_seq if comp.last_seq is not None else -1)
        h["bad-lines"], h["lost-lines"] = comp.bad_lines, comp.lost_lines
        h["holds"], h["restarts"] = comp.holds, comp.restarts
        h["zero-acks"], h["zero-seq"] = comp.zero_acks, _s32(comp.zero_seq)
        for a in self.cfg.axes:
            h[f"{a.letter}.offset"] = a.want * self.scale(a)
            h[f"{a.letter}.correction-nm"] = a.box_nm


def _s32(value: int) -> int:
    value %= 1 << 32
    return value - (1 << 32) if value >= 1 << 31 else value


def handle_line(comp: Compensator, port: Port, raw: bytes, now: float) -> None:
    if not raw:
        return
    try:
        msg = protocol.decode(raw)
    except protocol.ProtocolError as exc:
        comp.bad_line(raw, exc)
        return
    if isinstance(msg, protocol.Sample):
        comp.take_sample(msg, now)
        if comp.restarts and comp.info is not None and msg.seq == 0:
            port.write(b"INFO\r\n")  # a restarted box may carry another model
    elif isinstance(msg, protocol.Info):
        comp.take_info(msg)
    elif isinstance(msg, protocol.Ack) and msg.command == "ZERO":
        comp.zeroed(msg.value)
    elif isinstance(msg, protocol.ErrorReply):
        comp.log(f"box refused a command: {msg.reason}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog=NAME, description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", required=True, help="component config file (thermalcomp.conf)")
    ap.add_argument("--name", default=NAME, help="HAL component name (default thermalcomp)")
    args = ap.parse_args(argv)
    try:
        cfg = load_config(args.config)
    except ConfigError as exc:
        print(f"{NAME}: {exc}", file=sys.stderr)
        return 2
    comp = Compensator(cfg)
    driver = HalDriver(cfg, comp, args.name)
    port = Port(cfg.port, cfg.baud)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    next_open = next_info = 0.0
    import select

    try:
        while not stop:
            now = time.monotonic()
            if port.fd is None and now >= next_open:
                if port.open():
                    comp.log(f"opened {cfg.port}")
                    next_info = now
                else:
                    next_open = now + 0.5
            if port.fd is not None and comp.info is None and now >= next_info:
                port.write(b"INFO\r\n")  # ask rather than wait for a banner
                next_info = now + 1.0
            if port.fd is not None:
                ready, _, _ = select.select([port.fd], [], [], cfg.poll_s)
                if ready:
                    lines = port.read_lines()
                    if lines is None:
                        comp.log(f"{cfg.port} closed: offsets held, reopening")
                        port.close()
                        comp.info = None
                        next_open = time.monotonic() + 0.2
                    else:
                        t = time.monotonic()
                        for raw in lines:
                            handle_line(comp, port, raw, t)
            else:
                time.sleep(cfg.poll_s)
            driver.update(time.monotonic(), port)
    except KeyboardInterrupt:
        pass
    finally:
        port.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
