"""One machine's connection to the broker (``Publisher``): every message QoS 1 (the state
retained) through paho-mqtt's own queue, so while the broker is away they wait in memory and go
out in order; with a spool (host.fleet.spool) each is on disk until the broker acknowledges
it. The last will marks the machine offline; commands come in here when a user may send them.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from thermal_comp.host.fleet.broker import BrokerUrl, make_client, parse_url
from thermal_comp.host.fleet.remote_commands import Command, parse_command
from thermal_comp.host.fleet.spool import Spool, message_key
from thermal_comp.host.fleet.topics import (
    OFFLINE,
    ONLINE,
    FleetError,
    check_machine,
    command_topic,
    encode,
    topic,
)

# the gateway's log, as before the publisher had its own module: one name in a service's journal
log = logging.getLogger("thermal_comp.host.fleet.gateway")


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
