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

Its parts: the translation (host.fleet.translator), the connection to the broker
(host.fleet.publisher) and the commands (host.fleet.remote_commands); here the relay between
them and the serial loop. Their names stay importable from here.
"""

from __future__ import annotations

import logging
import queue
import time
from collections.abc import Callable
from typing import Any

from thermal_comp.contract import protocol
from thermal_comp.host.fleet.broker import BrokerUrl
from thermal_comp.host.fleet.publisher import Publisher as Publisher
from thermal_comp.host.fleet.remote_commands import COMMAND_MAX_AGE_S as COMMAND_MAX_AGE_S
from thermal_comp.host.fleet.remote_commands import COMMANDS as COMMANDS
from thermal_comp.host.fleet.remote_commands import Command as Command
from thermal_comp.host.fleet.remote_commands import parse_command as parse_command
from thermal_comp.host.fleet.spool import Spool
from thermal_comp.host.fleet.translator import BAD_EVENT_EVERY_S as BAD_EVENT_EVERY_S
from thermal_comp.host.fleet.translator import FAULT_FLAGS
from thermal_comp.host.fleet.translator import BoxState as BoxState
from thermal_comp.host.fleet.translator import Translator as Translator
from thermal_comp.host.fleet.translator import channel_fault_names as channel_fault_names

log = logging.getLogger("thermal_comp.host.fleet.gateway")

INFO_RETRY_S = 1.0
STATUS_EVERY_S = 1.0


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
                    self._want_status(frozenset(msg["flags"]) & FAULT_FLAGS, mono)
        if len(self._buf) > 1024:
            self.relay.line(bytes(self._buf[:200]), now)
            self._buf.clear()

    def _want_status(self, flags: frozenset[str], mono: float) -> None:
        if flags and (flags != self._fault_flags or mono - self._status_at >= STATUS_EVERY_S):
            self._write(protocol.encode_command("STATUS"))
            self._status_at = mono
        self._fault_flags = flags
