"""`host gateway PORT --mqtt URL --machine NAME`: one box's serial lines to the broker.

Headless (a service, one per box): reads the box's lines, asks INFO (names, model hash) and
STATUS (which channel is faulted) as ``host monitor`` does, and publishes each sample as the
machine's retained state, plus events (topics.py). Publishing is QoS 1 through paho-mqtt's
own queue: while the broker is away the messages wait in memory and go out in order when it
is back. With a spool (host.fleet.spool; ``host gateway`` has one by default) every message is
also on disk until the broker acknowledges it, and a gateway started again re-publishes what
an earlier one left unacknowledged: a gateway killed during an outage loses nothing
(docs/fleet.md). The last will marks the machine offline.

``BoxRelay`` (box lines -> Translator -> Publisher) is the publishing both ``host gateway``
and ``host monitor --mqtt`` run: the same messages from the same lines.

A line the decoder does not know but whose CRC is good (a newer box: a MEAS answer
``$OK,MEAS,...`` or a ``$M`` line) is published as an event, never an error; a MEAS answer's
innovation becomes the machine's last probe residual. Lines that fail their CRC are counted
and published as ``bad_line`` events (at most one a second, with the count).

Commands: none, unless the gateway was started with ``--allow-commands USER,...`` for its
machine and connects as an authenticated user. It then reads ``thermalcomp/<machine>/cmd/<user>``
(the broker's ACL makes ``<user>`` the publisher: docs/fleet.md), takes ZERO, STATUS, INFO or
RATE n from the users named, refuses commands older than ``COMMAND_MAX_AGE_S``, and logs and
publishes every command with its user and outcome.
"""

from __future__ import annotations

import json
import logging
import queue
import re
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from thermal_comp.contract import protocol
from thermal_comp.host.fleet.broker import BrokerUrl, make_client, parse_url
from thermal_comp.host.fleet.spool import Spool, message_key
from thermal_comp.host.fleet.topics import (
    OFFLINE,
    ONLINE,
    SCHEMA,
    FleetError,
    check_machine,
    command_topic,
    encode,
    topic,
)

log = logging.getLogger("thermal_comp.host.fleet.gateway")

_LINE_RE = re.compile(rb"\$([\x20-\x7e]*)\*([0-9A-F]{4})")
_INT_RE = re.compile(r"-?[0-9]+")
INFO_RETRY_S = 1.0
STATUS_EVERY_S = 1.0
BAD_EVENT_EVERY_S = 1.0
COMMAND_MAX_AGE_S = 10.0
COMMANDS = ("ZERO", "STATUS", "INFO", "RATE")
_FAULT_FLAGS = {"HOLD", "RANGE", "OPEN", "TC_FAULT", "AUX_FAULT", "NO_DATA", "IMPLAUSIBLE",
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
        if not set(flags) & _FAULT_FLAGS:
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


@dataclass
class Command:
    user: str
    text: str
    line: bytes


def parse_command(payload: bytes, now: float) -> tuple[str, bytes]:
    """A command message -> (its text, the line for the box). ``payload``: JSON
    ``{"command": "ZERO", "t": <unix s>}``. Raises ValueError with the reason."""
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError):
        raise ValueError("not JSON ({\"command\": \"ZERO\", \"t\": <unix s>})") from None
    if not isinstance(data, dict) or not isinstance(data.get("command"), str):
        raise ValueError("no \"command\" field")
    t = data.get("t")
    if not isinstance(t, int | float) or isinstance(t, bool):
        raise ValueError("no \"t\" (the time it was sent): a command without one could be "
                         "an old one replayed")
    if abs(now - t) > COMMAND_MAX_AGE_S:
        raise ValueError(f"sent {now - t:.0f} s ago (more than {COMMAND_MAX_AGE_S:g} s): "
                         "not executed")
    words = data["command"].split()
    if not words or words[0] not in COMMANDS:
        raise ValueError(f"command {data['command'][:40]!r} is not one of "
                         f"{', '.join(COMMANDS)}")
    try:
        arg = int(words[1]) if len(words) == 2 and words[0] == "RATE" else None
        if len(words) != (2 if words[0] == "RATE" else 1):
            raise ValueError
        line = protocol.encode_command(words[0], arg)
    except (ValueError, protocol.InputError) as exc:
        raise ValueError(f"command {data['command'][:40]!r}: bad argument {exc}") from None
    return " ".join(words), line


class Publisher:
    """One machine's connection to the broker: publishes messages QoS 1 (state retained),
    marks the machine online/offline, and, when enabled, receives its commands.

    With a ``spool`` each message is written to it before it is published and acknowledged
    in it on its PUBACK; ``start`` first re-publishes what the spool recovered."""

    def __init__(self, url: str | BrokerUrl, machine: str, gateway_id: str,
                 allow_users: frozenset[str] = frozenset(),
                 on_command: Callable[[Command], None] | None = None,
                 spool: Spool | None = None) -> None:
        self.url = parse_url(url) if isinstance(url, str) else url
        self.machine = check_machine(machine)
        if allow_users and not self.url.user:
            raise FleetError("--allow-commands needs an authenticated broker connection "
                             "(mqtt://user:password@host): the broker's ACL is what makes a "
                             "command's user its sender")
        self.allow_users = allow_users
        self.on_command = on_command
        self.command_log: list[tuple[str, str, str]] = []  # (user, command, outcome)
        self.command_sink: Callable[..., None] | None = None  # publishes the command event
        self.connected = False
        self.published = 0
        self.spool = spool
        self.republished = 0  # messages an earlier run left in the spool, sent again
        # PUBACKs matched to spooled messages by paho's message id (on_publish gives only the
        # id, and may come before publish() has returned the id to us: ``_early``); ids of
        # messages not spooled (online/offline) are ``_unspooled``
        self._acks_lock = threading.Lock()
        self._by_mid: dict[int, str] = {}
        self._early: set[int] = set()
        self._unspooled: set[int] = set()
        # clean session: commands sent while the gateway was away are not queued for it;
        # its own outgoing QoS 1 messages are kept and resent by paho all the same
        self.client = make_client(self.url, f"tc-gw-{machine}-{gateway_id}",
                                  clean_session=True, will_topic=topic(machine, "online"),
                                  will_payload=OFFLINE)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message
        self.client.on_publish = self._on_publish

    def start(self) -> None:
        if self.spool is not None:  # an earlier run's unacknowledged messages go out first
            for kind, data in self.spool.recovered:
                self._send(kind, data, message_key(data))
            self.republished = len(self.spool.recovered)
            self.spool.recovered = []
        self.client.connect_async(self.url.host, self.url.port, keepalive=10)
        self.client.loop_start()

    def _on_connect(self, client, userdata, flags, reason_code, properties) -> None:
        if reason_code.is_failure:
            log.warning("%s: broker %s refused the connection: %s", self.machine, self.url,
                        reason_code)
            return
        self.connected = True
        log.info("%s: connected to %s", self.machine, self.url)
        self._publish_unspooled(topic(self.machine, "online"), ONLINE)
        if self.allow_users:
            client.subscribe(command_topic(self.machine, "+"), qos=1)

    def _on_disconnect(self, client, userdata, flags, reason_code, properties) -> None:
        if self.connected:
            log.warning("%s: lost the broker (%s); queueing until it is back", self.machine,
                        reason_code)
        self.connected = False

    def _on_message(self, client, userdata, msg) -> None:
        user = msg.topic.rsplit("/", 1)[-1]
        now = time.time()
        if user not in self.allow_users:
            self._command_event(user, "?", f"refused: user {user!r} may not command "
                                f"{self.machine}", now)
            return
        try:
            text, line = parse_command(msg.payload, now)
        except ValueError as exc:
            self._command_event(user, "?", f"refused: {exc}", now)
            return
        self._command_event(user, text, "accepted: sent to the box", now)
        if self.on_command is not None:
            self.on_command(Command(user, text, line))

    def _command_event(self, user: str, text: str, outcome: str, now: float) -> None:
        log.warning("%s: command %s from user %s: %s", self.machine, text, user, outcome)
        self.command_log.append((user, text, outcome))
        if self.command_sink is not None:
            self.command_sink("command", f"command {text} from {user}: {outcome}", now,
                              user=user, command=text, outcome=outcome)

    def publish(self, kind: str, data: dict) -> None:
        key = message_key(data)
        if self.spool is not None:
            self.spool.add(key, kind, data)  # on disk before paho has it
        self._send(kind, data, key)
        self.published += 1

    def _send(self, kind: str, data: dict, key: str) -> None:
        info = self.client.publish(topic(self.machine, kind), encode(data), qos=1,
                                   retain=kind == "state")
        if self.spool is None:
            return
        with self._acks_lock:  # never held while calling paho (its lock, then ours)
            if info.mid in self._early:
                self._early.discard(info.mid)
                acked = True
            else:
                self._by_mid[info.mid] = key
                acked = False
        if acked:
            self.spool.ack(key)

    def _publish_unspooled(self, topic_name: str, payload: str):
        info = self.client.publish(topic_name, payload, qos=1, retain=True)
        if self.spool is not None:
            with self._acks_lock:
                self._unspooled.add(info.mid)
        return info

    def _on_publish(self, client, userdata, mid, reason_code, properties) -> None:
        if self.spool is None:
            return
        with self._acks_lock:
            key = self._by_mid.pop(mid, None)
            if key is None and mid in self._unspooled:
                self._unspooled.discard(mid)
            elif key is None:
                self._early.add(mid)  # publish() has not told us the id yet
        if key is not None:
            self.spool.ack(key)

    def pending(self) -> int:
        """Messages not yet acknowledged by the broker (queued or in flight)."""
        return len(self.client._out_messages)  # paho keeps no public count

    def stop(self, timeout_s: float | None = None) -> None:
        """Wait (up to timeout_s: 10 s, 2 s with a spool, which keeps the rest) until
        everything queued is acknowledged, say offline, and disconnect."""
        if timeout_s is None:
            timeout_s = 10.0 if self.spool is None else 2.0
        deadline = time.monotonic() + timeout_s
        while self.pending() and time.monotonic() < deadline:
            time.sleep(0.05)
        if self.pending():
            if self.spool is not None:
                log.warning("%s: %d message(s) not acknowledged by the broker at stop: kept in "
                            "%s, published again at the next start", self.machine,
                            self.spool.pending(), self.spool.path)
            else:
                log.warning("%s: %d message(s) not acknowledged by the broker at stop: lost",
                            self.machine, self.pending())
        info = self._publish_unspooled(topic(self.machine, "online"), OFFLINE)
        if self.connected:
            try:
                info.wait_for_publish(timeout=2)
            except (RuntimeError, ValueError):
                pass
        self.client.disconnect()
        self.client.loop_stop()
        if self.spool is not None:
            self.spool.close()


class BoxRelay:
    """One box's lines to the broker: Translator -> Publisher. What ``host gateway`` and
    ``host monitor --mqtt`` both run, so the broker gets the same messages from either: feed
    it every line the box sends (``line``), say when the serial link comes and goes
    (``connected``, ``lost``), ``start`` and ``stop`` it."""

    def __init__(self, mqtt_url: str | BrokerUrl, machine: str,
                 allow_users: frozenset[str] = frozenset(),
                 on_command: Callable[[Command], None] | None = None,
                 spool: Spool | None = None) -> None:
        self.translator = Translator(machine)
        self.publisher = Publisher(mqtt_url, machine, self.translator.gateway_id, allow_users,
                                   on_command=on_command, spool=spool)
        self.publisher.command_sink = self.event

    def start(self) -> None:
        self.publisher.start()

    def stop(self) -> None:
        self.publisher.stop()

    def emit(self, messages: list[tuple[str, dict]]) -> None:
        for kind, data in messages:
            self.publisher.publish(kind, data)

    def line(self, raw: bytes, now: float) -> list[tuple[str, dict]]:
        """Translate and publish one line; the messages it made."""
        out = self.translator.line(raw, now)
        self.emit(out)
        return out

    def event(self, event: str, message: str, now: float, **extra: Any) -> None:
        self.emit([self.translator.event(event, message, now, **extra)])

    def connected(self, port: str, now: float) -> None:
        self.event("connected", f"serial port {port} open", now)

    def lost(self, why: str, now: float) -> None:
        self.event("lost", f"serial port lost ({why}); retrying", now)
        self.translator.box.info = None  # another box may come back on the port: ask again


class Gateway:
    """Serial port -> BoxRelay, with INFO/STATUS queries and commands."""

    def __init__(self, port: str, mqtt_url: str, machine: str, baud: int = 115200,
                 allow_users: frozenset[str] = frozenset(), retry_s: float = 1.0,
                 spool: Spool | None = None) -> None:
        self.port_name, self.baud, self.retry_s = port, baud, retry_s
        self.commands: queue.Queue[Command] = queue.Queue()
        self.relay = BoxRelay(mqtt_url, machine, allow_users, on_command=self.commands.put,
                              spool=spool)
        self.translator, self.publisher = self.relay.translator, self.relay.publisher
        self._port = None
        self._buf = bytearray()
        self._info_at: float | None = None
        self._status_at = 0.0
        self._fault_flags: frozenset[str] = frozenset()

    def _open(self) -> bool:
        import serial  # the [fleet] extra brings pyserial

        try:
            if "://" in self.port_name:
                self._port = serial.serial_for_url(self.port_name, baudrate=self.baud,
                                                   timeout=0.05)
            else:
                self._port = serial.Serial(self.port_name, baudrate=self.baud, timeout=0.05)
        except (OSError, serial.SerialException) as exc:
            log.debug("cannot open %s: %s", self.port_name, exc)
            self._port = None
            return False
        self._buf.clear()
        self.relay.connected(self.port_name, time.time())
        self._write(protocol.encode_command("INFO"))
        self._info_at = time.monotonic()
        return True

    def _write(self, line: bytes) -> None:
        if self._port is not None:
            self._port.write(line)
            self._port.flush()

    def run(self, duration: float | None = None, count: int | None = None) -> int:
        import serial

        self.relay.start()
        start = time.monotonic()
        next_try = 0.0
        try:
            while duration is None or time.monotonic() - start < duration:
                if count is not None and self.translator.box.samples >= count:
                    break
                if self._port is None:
                    if time.monotonic() >= next_try and not self._open():
                        next_try = time.monotonic() + self.retry_s
                    time.sleep(0.05)
                    continue
                try:
                    self._poll()
                    while not self.commands.empty():
                        self._write(self.commands.get_nowait().line)
                except (OSError, serial.SerialException) as exc:
                    self.relay.lost(str(exc), time.time())
                    try:
                        self._port.close()
                    except (OSError, serial.SerialException):
                        pass
                    self._port = None
                    next_try = time.monotonic() + self.retry_s
        except KeyboardInterrupt:
            pass
        finally:
            if self._port is not None:
                self._port.close()
            self.relay.stop()
        return 0

    def _poll(self) -> None:
        assert self._port is not None
        data = self._port.read(max(1, min(4096, self._port.in_waiting)))
        mono, now = time.monotonic(), time.time()
        box = self.translator.box
        if box.info is None and self._info_at is not None and mono - self._info_at > \
                INFO_RETRY_S:
            self._write(protocol.encode_command("INFO"))
            self._info_at = mono
        if not data:
            return
        self._buf += data
        while b"\n" in self._buf:
            line, _, rest = bytes(self._buf).partition(b"\n")
            self._buf = bytearray(rest)
            out = self.relay.line(line, now)
            for kind, msg in out:
                if kind == "state":
                    self._want_status(frozenset(msg["flags"]) & _FAULT_FLAGS, mono)
        if len(self._buf) > 1024:
            self.relay.line(bytes(self._buf[:200]), now)
            self._buf.clear()

    def _want_status(self, flags: frozenset[str], mono: float) -> None:
        if flags and (flags != self._fault_flags or mono - self._status_at >= STATUS_EVERY_S):
            self._write(protocol.encode_command("STATUS"))
            self._status_at = mono
        self._fault_flags = flags
