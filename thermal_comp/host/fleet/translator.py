"""One box's lines as the fleet's messages (``Translator``): each sample the machine's state,
everything else an event (topics.py). No I/O, so the gateway, ``host monitor --mqtt``, the
tests and the bench all drive the same translation.

A line the decoder does not know but whose CRC is good (a newer box: a MEAS answer
``$OK,MEAS,...`` or a ``$M`` line) is published as an event, never an error; a MEAS answer's
innovation becomes the machine's last probe residual. Lines that fail their CRC are counted
and published as ``bad_line`` events (at most one a second, with the count).
"""

from __future__ import annotations

import re
import threading
import uuid
from dataclasses import dataclass, field
from typing import Any

from thermal_comp.contract import protocol
from thermal_comp.host.fleet.topics import SCHEMA, check_machine

_LINE_RE = re.compile(rb"\$([\x20-\x7e]*)\*([0-9A-F]{4})")
_INT_RE = re.compile(r"-?[0-9]+")
BAD_EVENT_EVERY_S = 1.0
# the status flags of a channel fault: a state with one makes the gateway ask STATUS
FAULT_FLAGS = {"HOLD", "RANGE", "OPEN", "TC_FAULT", "AUX_FAULT", "NO_DATA", "IMPLAUSIBLE",
               "BEYOND"}


def channel_fault_names(word: int) -> list[str]:
    names = [f.name for f in protocol.ChannelFault if word & f.value and f.name]
    return names or [f"0x{word:04X}"]


@dataclass
class BoxState:
    """What the gateway knows of its box between lines."""

    info: protocol.Info | None = None
    faults: dict[str, list[str]] = field(default_factory=dict)
    probe: dict[str, Any] | None = None
    bad_lines: int = 0
    bad_reported: int = 0
    last_bad_event: float = 0.0
    samples: int = 0


class Translator:
    """Box lines -> (kind, JSON object) messages for the broker; no I/O, so tests and the
    bench drive it directly."""

    def __init__(self, machine: str, gateway_id: str | None = None) -> None:
        self.machine = check_machine(machine)
        self.gateway_id = gateway_id or uuid.uuid4().hex[:12]
        self.n = 0
        self.box = BoxState()
        self._lock = threading.Lock()  # commands' events come from paho's thread

    def _message(self, kind: str, now: float, body: dict[str, Any]) -> tuple[str, dict]:
        with self._lock:
            self.n += 1
            n = self.n
        return kind, {"schema": SCHEMA, "machine": self.machine, "gateway": self.gateway_id,
                      "n": n, "t": round(now, 3), **body}

    def event(self, event: str, message: str, now: float, **extra: Any) -> tuple[str, dict]:
        return self._message("event", now, {"event": event, "message": message, **extra})

    def _names(self, names: tuple[str, ...] | None, n: int, prefix: str) -> list[str]:
        have = list(names or ())[:n]
        return have + [f"{prefix}{i}" for i in range(len(have), n)]

    def line(self, raw: bytes, now: float) -> list[tuple[str, dict]]:
        raw = raw.rstrip(b"\r\n")
        if not raw.strip():
            return []
        try:
            message = protocol.decode(raw)
        except protocol.ProtocolError as exc:
            return self._undecoded(raw, str(exc), now)
        box = self.box
        if isinstance(message, protocol.Info):
            out = []
            before = box.info
            box.info = message
            text = (f"firmware {message.fw_version}, model {message.model_hash} (CRC "
                    f"{'OK' if message.crc_ok else 'BAD'}), period {message.period_ms} ms")
            out.append(self.event("info", text, now, model_hash=message.model_hash,
                                  fw=message.fw_version, crc_ok=message.crc_ok,
                                  axes=list(message.axes),
                                  channels=[c.sensor for c in message.channels]))
            if before is not None and before.model_hash != message.model_hash:
                out.append(self.event(
                    "model_changed", f"the box now runs model {message.model_hash}, not "
                    f"{before.model_hash}", now, model_hash=message.model_hash,
                    previous=before.model_hash))
            return out
        if isinstance(message, protocol.StatusReport):
            names = self._names(tuple(c.sensor for c in box.info.channels) if box.info else (),
                                len(message.channel_faults), "ch")
            box.faults = {names[i]: channel_fault_names(w)
                          for i, w in enumerate(message.channel_faults) if w}
            return []
        if isinstance(message, protocol.Sample):
            return [self._sample(message, now)]
        if isinstance(message, protocol.Ack):
            return [self.event("reply", f"OK {message.command} {message.value}", now,
                               reply="OK", command=message.command, value=message.value)]
        if isinstance(message, protocol.ErrorReply):
            return [self.event("reply", f"E {message.reason}", now, reply="E",
                               reason=message.reason)]
        # a kind the decoder knows but this gateway does not (a MEAS answer, a newer line)
        return self._undecoded(raw, "", now)

    def _sample(self, s: protocol.Sample, now: float) -> tuple[str, dict]:
        box, info = self.box, self.box.info
        box.samples += 1
        flags = protocol.status_names(s.status)
        if not set(flags) & FAULT_FLAGS:
            box.faults = {}
        axes = self._names(info.axes if info else None, len(s.corrections_nm), "axis")
        chans = self._names(tuple(c.sensor for c in info.channels) if info else None,
                            len(s.temp_codes), "ch")
        return self._message("state", now, {
            "seq": s.seq, "status": f"{s.status:04X}", "flags": flags,
            "corrections_um": {a: nm / 1000.0 for a, nm in zip(axes, s.corrections_nm,
                                                                strict=True)},
            "temperatures_c": {c: (None if c in box.faults else code / 128.0)
                               for c, code in zip(chans, s.temp_codes, strict=True)},
            "faults": dict(box.faults),
            "model_hash": info.model_hash if info else None,
            "period_ms": info.period_ms if info else None,
            "probe": box.probe,
        })

    def _undecoded(self, raw: bytes, why: str, now: float) -> list[tuple[str, dict]]:
        text = raw[:200].decode("ascii", errors="backslashreplace")
        m = _LINE_RE.fullmatch(raw)
        if m and int(m.group(2), 16) == protocol.crc16(m.group(1)):
            fields = m.group(1).decode("ascii").split(",")
            if fields[:2] == ["OK", "MEAS"] or fields[0] == "M":
                return [self._probe(fields, text, now)]
            return [self.event("unknown_line", f"a line this gateway does not know (CRC "
                               f"good, kind {fields[0]!r}): published as it is", now,
                               line=text)]
        box = self.box
        box.bad_lines += 1
        if now - box.last_bad_event < BAD_EVENT_EVERY_S:
            return []
        box.last_bad_event = now
        count, box.bad_reported = box.bad_lines - box.bad_reported, box.bad_lines
        return [self.event("bad_line", f"{why[:200]} ({count} bad line(s) since the last "
                           "report)", now, line=text, count=count, total=box.bad_lines)]

    def _probe(self, fields: list[str], text: str, now: float) -> tuple[str, dict]:
        """A MEAS answer: the firmware's ``$M,<axis>,<seq>,<A|R>,<reason>,<innovation_nm>,...``
        (issue 42) gives the residual exactly; any other layout (``$OK,MEAS,...``) is read
        leniently: the first axis name and the first integer after it. The raw fields always
        go along."""
        rest = fields[2:] if fields[0] == "OK" else fields[1:]
        axes = list(self.box.info.axes) if self.box.info else []
        residual: dict[str, float] = {}
        seq = None
        # the firmware's $M,<axis>,<seq>,<A|R>,<reason|->,<innovation_nm|->,<bias_nm|->,<p|->
        if fields[0] == "M" and len(rest) >= 5 and rest[2] in ("A", "R"):
            if _INT_RE.fullmatch(rest[4]):
                residual[rest[0]] = int(rest[4]) / 1000.0
            seq = int(rest[1]) if _INT_RE.fullmatch(rest[1]) else None
            rest = []
        for i, f in enumerate(rest):
            if f in axes or (not axes and not _INT_RE.fullmatch(f) and f):
                nums = [int(x) for x in rest[i + 1:] if _INT_RE.fullmatch(x)]
                if nums:
                    residual[f] = nums[0] / 1000.0
                break
            if seq is None and _INT_RE.fullmatch(f):
                seq = int(f)
        flags_ = fields[2:] if fields[0] == "OK" else fields[1:]
        accepted = next((f for f in flags_ if f in ("A", "R", "ACCEPTED", "REFUSED")), None)
        if residual:
            self.box.probe = {"residual_um": residual, "t": round(now, 3), "seq": seq,
                              "accepted": accepted}
        return self.event("probe", "probe answer: " + (", ".join(
            f"{a} residual {v:+.3f}" for a, v in residual.items()) or "no residual read"),
            now, line=text, fields=flags_, residual_um=residual)
