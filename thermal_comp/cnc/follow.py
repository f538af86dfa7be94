"""The LinuxCNC component's logic following the box's lines offline (`make faults`): the lines
a HIL replay captured, in the order the box sent them, plus what happens on the wire between
the box and the controller (a forged line, garbage, a silent or dropped link), turned into the
offsets the component would command per sample."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from thermal_comp.cnc.thermalcomp import AxisMap, Compensator, Config, Port, handle_line
from thermal_comp.contract import protocol
from thermal_comp.contract.model_spec import ModelSpec
from thermal_comp.hil.checks import step_limits_nm
from thermal_comp.hil.runner import Capture


# --- what happens on the wire between the box and the controller -------------------------
@dataclass(frozen=True)
class Forge:
    """After the line of sample ``after``: a CRC-valid ``$C`` line with the next seq and every
    correction moved by ``delta_nm`` (a forged or damaged-but-valid line)."""

    after: int
    delta_nm: int = 60_000


@dataclass(frozen=True)
class Garbage:
    """After the line of sample ``after``: these bytes arrive at the component."""

    after: int
    data: bytes


@dataclass(frozen=True)
class Silence:
    """The lines of samples [start, stop) never reach the component (a stale stream); with
    ``reconnect`` the port closed at ``start`` and opened again at ``stop`` (a USB-serial
    adapter unplugged and plugged in: the component asks INFO again)."""

    start: int
    stop: int
    reconnect: bool = False


WireEvent = Forge | Garbage | Silence


# --- the controller, following the box ----------------------------------------------------
class _Wire:
    """The component's port, offline: what it writes is noted (INFO, ZERO)."""

    def __init__(self) -> None:
        self.asked_info = False
        self.sent_zero = False
        self.port = Port("(campaign)", 115200)
        self.port.synced = True

    def write(self, data: bytes) -> bool:
        if data.startswith(b"INFO"):
            self.asked_info = True
        elif data.startswith(b"ZERO"):
            self.sent_zero = True
        return True


@dataclass
class Followed:
    """Per sample: the offset the component commands (nm, box units) and whether it held."""

    offset_nm: np.ndarray  # (n, n_axes)
    holding: np.ndarray  # (n,) bool
    walking: np.ndarray  # (n,) bool: walking back to the box's value after a hold
    box_status: np.ndarray  # (n,) the box's status word on that sample's line (-1: none)
    flags: set[str] = field(default_factory=set)
    log: list[str] = field(default_factory=list)
    touch_offs: list[int] = field(default_factory=list)  # samples of the datums in force
    zero_resent_after: list[int] = field(default_factory=list)  # the component's own ZEROs


class _Follower:
    """The component's logic fed the box's lines as they came, with the wire's events."""

    def __init__(self, model: ModelSpec, axes: Sequence[str], n: int,
                 wire: Sequence[WireEvent]) -> None:
        self.period = model.sample_period_s
        steps = step_limits_nm(model)
        self.cfg = Config(port="(campaign)", axes=[AxisMap(a, a, 1, 1.0, float(steps[a]))
                                                   for a in axes],
                          model_hash=model.model_hash)
        self.out = Followed(np.zeros((n, len(axes))), np.zeros(n, dtype=bool),
                            np.zeros(n, dtype=bool), np.full(n, -1, dtype=np.int64))
        self.comp = Compensator(self.cfg, log=self.out.log.append)
        self.port = _Wire()
        self.wire = wire
        self.silent = [w for w in wire if isinstance(w, Silence)]
        self.info_line = b""
        self.k = 0

    def deliver(self, raw: bytes, t: float) -> None:
        comp, port = self.comp, self.port
        handle_line(comp, port, raw, t)  # type: ignore[arg-type]  (write() is all it uses)
        if port.asked_info and self.info_line:
            port.asked_info = False
            handle_line(comp, port, self.info_line, t)  # the box answers INFO

    def session(self, s) -> None:
        """One power-up of the box: the samples it was off for, then its lines."""
        while self.k < s.first_sample:  # off (Restart.off): no line, the offsets hold
            self.comp.check_stale(self.k * self.period)
            _record(self.out, self.comp, self.k, -1)
            self.k += 1
        zero_replies = list(s.zero_acks)
        for raw in s.lines:
            if raw.startswith(b"$I,"):
                self.info_line = raw
            if self.lost(raw):
                continue
            if zero_replies and raw == zero_replies[0]:
                zero_replies.pop(0)
                self.zero_answered(raw)
            self.line(raw)

    def lost(self, raw: bytes) -> bool:
        """The line never reaches the component (a silent or dropped link)."""
        comp, k = self.comp, self.k
        gone = next((w for w in self.silent if w.start <= k < w.stop), None)
        if gone is None:
            return False
        if gone.reconnect and k == gone.start and comp.info_fresh:
            comp.info_fresh = False  # as main() does when the port goes away
            self.out.log.append("port closed: offsets held, reopening")
        if raw.startswith(b"$C,"):
            comp.check_stale(k * self.period)
            _record(self.out, comp, k, -1)
            self.k += 1
        return True

    def zero_answered(self, raw: bytes) -> None:
        self.comp.zero_sent()
        if raw.startswith(b"$E,"):
            self.out.flags.add("ZERO refused: " + raw.decode(errors="replace").split("*")[0])
        else:  # the operator touches off once the ZERO is acknowledged
            self.out.touch_offs.append(self.k)

    def line(self, raw: bytes) -> None:
        comp, k, out, t = self.comp, self.k, self.out, self.k * self.period
        if any(w.reconnect and w.stop == k for w in self.silent) and comp.needs_info():
            handle_line(comp, self.port, self.info_line, t)  # reopened: the component asks INFO
        self.deliver(raw, t)
        comp.check_stale(t)
        if not raw.startswith(b"$C,"):
            return
        msg = protocol.decode(raw)
        assert isinstance(msg, protocol.Sample)
        _record(out, comp, k, msg.status)
        if self.port.sent_zero:  # a deferred ZERO: the runner must send it before sample k+1
            self.port.sent_zero = False
            out.zero_resent_after.append(k)
            out.flags.add("ZERO deferred and sent again")
        for w in self.wire:
            if isinstance(w, Forge) and w.after == k:
                forged = protocol.encode_sample(
                    msg.seq + 1, msg.status,
                    [c + w.delta_nm for c in msg.corrections_nm], msg.temp_codes)
                self.deliver(forged.rstrip(b"\r\n"), t)
                out.offset_nm[k] = [a.want for a in self.cfg.axes]  # what the forged line did
                out.flags.add("forged line taken (bounded)" if comp.bad_lines == 0
                              else "forged line refused")
            elif isinstance(w, Garbage) and w.after == k:
                for line in self.port.port.feed(w.data):
                    self.deliver(line, t)
        self.k += 1


def follow(model: ModelSpec, capture: Capture, axes: Sequence[str],
           wire: Sequence[WireEvent] = ()) -> Followed:
    """Feed the box's lines, in the order it sent them, to the component's logic."""
    f = _Follower(model, axes, capture.n_samples, wire)
    for s in capture.sessions:
        f.session(s)
    comp, out = f.comp, f.out
    if comp.bad_lines:
        out.flags.add(f"bad-lines {comp.bad_lines}")
    if comp.restarts:
        out.flags.add(f"restarts {comp.restarts}")
    return out



def _record(out: Followed, comp: Compensator, k: int, status: int) -> None:
    if k >= len(out.holding):
        return
    out.offset_nm[k] = [a.want for a in comp.cfg.axes]
    out.holding[k] = comp.holding or bool(comp.hold_reason)
    out.walking[k] = comp.walking
    out.box_status[k] = status
    if comp.hold_reason:
        out.flags.add("held: " + comp.hold_reason)
    if comp.await_zero:
        out.flags.add("awaiting-zero")
    if comp.stale:  # what the component said, not what the scenario did
        out.flags.add("stale")
