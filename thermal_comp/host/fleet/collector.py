"""`host fleet serve`: subscribe to every machine and store what they send.

A persistent MQTT session (clean_session off, a fixed client id, QoS 1): while the service is
down or the broker restarts, the broker keeps the machines' messages for it (mosquitto with
``persistence true``), and a message is acknowledged only once its row is committed, so a
crash between receipt and commit means a resend, never a loss (the store drops duplicates).

Nothing a message holds can stop the service: a malformed, oversized or unknown-kind message,
an unknown machine (when the fleet's machines are named) or a database error on one message
is refused with its reason, logged, and listed on the page; a changed or unexpected model hash
is stored and flagged.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Mapping

from thermal_comp.host.fleet.broker import BrokerUrl, make_client, parse_url
from thermal_comp.host.fleet.store import Store
from thermal_comp.host.fleet.topics import ROOT, Refused, parse

log = logging.getLogger("thermal_comp.host.fleet.collector")


class Collector:
    """Receives ``thermalcomp/#`` and writes it to ``store``.

    ``machines``: name -> expected model hash (or None). When given, only those machines are
    stored; any other is refused as unknown. Empty: every machine is enrolled on its first
    message (logged)."""

    def __init__(self, url: str | BrokerUrl, store: Store,
                 machines: Mapping[str, str | None] | None = None,
                 client_id: str | None = None) -> None:
        self.url = parse_url(url) if isinstance(url, str) else url
        self.store = store
        self.closed_registry = bool(machines)
        for name, expected in (machines or {}).items():
            store.register(name, expected)
        self.client_id = client_id or f"tc-fleet-{socket.gethostname()}"
        self.client = make_client(self.url, self.client_id, clean_session=False)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message
        self.received = 0
        self.stored = 0
        self.refused = 0
        self.connected = threading.Event()
        self._enrolled: set[str] = set()
        self._known: dict[str, bool] = {}

    def _on_connect(self, client, userdata, flags, reason_code, properties) -> None:
        if reason_code.is_failure:
            log.error("broker %s refused the connection: %s", self.url, reason_code)
            return
        log.info("connected to %s (session %s)", self.url,
                 "resumed" if flags.session_present else "new")
        client.subscribe(f"{ROOT}/#", qos=1)
        self.connected.set()

    def _on_disconnect(self, client, userdata, flags, reason_code, properties) -> None:
        if self.connected.is_set():
            log.warning("lost the broker (%s); reconnecting", reason_code)
        self.connected.clear()

    def _on_message(self, client, userdata, msg) -> None:
        self.received += 1
        machine = None
        try:
            parsed = parse(msg.topic, msg.payload)
            if parsed is None:
                return
            machine = parsed.machine
            if not self._is_known(machine):
                raise Refused(f"unknown machine {machine!r}: not one of the fleet's "
                              "(serve --machine)", machine)
            for note in self.store.add(parsed):
                log.warning("%s: %s", machine, note)
            self.stored += 1
        except Refused as exc:
            self._refuse(msg.topic, exc.machine or machine, exc.reason, msg.payload)
        except Exception as exc:  # noqa: BLE001 - one message must not stop the service
            log.exception("storing a message from %s failed", msg.topic)
            self._refuse(msg.topic, machine, f"not stored: {type(exc).__name__}: {exc}",
                         msg.payload)

    def _is_known(self, machine: str) -> bool:
        if not self.closed_registry:
            if machine not in self._enrolled:
                self._enrolled.add(machine)
                if not self.store.known(machine):
                    log.info("%s: enrolled on its first message", machine)
            return True
        if machine not in self._known:
            self._known[machine] = self.store.known(machine)
        return self._known[machine]

    def _refuse(self, topic: str, machine: str | None, reason: str, payload: bytes) -> None:
        self.refused += 1
        log.warning("refused a message on %s: %s", topic[:120], reason)
        try:
            self.store.refuse(topic, machine, reason, payload)
        except Exception:  # noqa: BLE001 - the database itself may be what failed
            log.exception("could not record the refusal")
            try:
                self.store.conn.rollback()
            except Exception:  # noqa: BLE001
                pass

    def start(self) -> None:
        self.client.connect_async(self.url.host, self.url.port, keepalive=10)
        self.client.loop_start()

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def run(self, duration: float | None = None) -> None:
        self.start()
        start = time.monotonic()
        try:
            while duration is None or time.monotonic() - start < duration:
                time.sleep(0.2)
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()
