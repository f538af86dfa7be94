"""Connecting to the MQTT broker: the URL, user/password, TLS, a paho-mqtt client.

``mqtt://[user[:password]@]host[:port]`` (1883) or ``mqtts://...`` (TLS, 8883). TLS options
as query parameters: ``?ca=/etc/thermalcomp/ca.pem`` (the CA that signed the broker's
certificate; default: the system's), ``&cert=...&key=...`` (a client certificate), and
``&insecure=1`` (no host name check: only for a test broker). The password may instead come
from the environment variable ``THERMALCOMP_MQTT_PASSWORD``, which keeps it off the command
line and out of ``ps``.
"""

from __future__ import annotations

import os
import ssl
from dataclasses import dataclass
from urllib.parse import parse_qs, unquote, urlsplit

from thermal_comp.host.fleet.topics import FleetError

PASSWORD_ENV = "THERMALCOMP_MQTT_PASSWORD"


@dataclass(frozen=True)
class BrokerUrl:
    host: str
    port: int
    tls: bool
    user: str | None = None
    password: str | None = None
    ca: str | None = None
    cert: str | None = None
    key: str | None = None
    insecure: bool = False

    def __str__(self) -> str:  # never the password
        who = f"{self.user}@" if self.user else ""
        return f"{'mqtts' if self.tls else 'mqtt'}://{who}{self.host}:{self.port}"


def parse_url(url: str) -> BrokerUrl:
    parts = urlsplit(url)
    if parts.scheme not in ("mqtt", "mqtts", "tcp", "ssl"):
        raise FleetError(f"broker URL {url!r}: use mqtt://host[:port] or mqtts://host[:port]")
    tls = parts.scheme in ("mqtts", "ssl")
    try:
        port = parts.port or (8883 if tls else 1883)
    except ValueError:
        raise FleetError(f"broker URL {url!r}: bad port") from None
    if not parts.hostname:
        raise FleetError(f"broker URL {url!r}: no host")
    query = {k: v[-1] for k, v in parse_qs(parts.query).items()}
    unknown = set(query) - {"ca", "cert", "key", "insecure"}
    if unknown:
        raise FleetError(f"broker URL: unknown option(s) {', '.join(sorted(unknown))} "
                         "(ca, cert, key, insecure)")
    if query and not tls:
        raise FleetError("broker URL: ca/cert/key/insecure need mqtts://")
    user = unquote(parts.username) if parts.username else None
    password = unquote(parts.password) if parts.password else os.environ.get(PASSWORD_ENV)
    return BrokerUrl(parts.hostname, port, tls, user, password if user else None,
                     query.get("ca"), query.get("cert"), query.get("key"),
                     query.get("insecure", "0") in ("1", "true", "yes"))


def make_client(url: BrokerUrl, client_id: str, clean_session: bool = True,
                will_topic: str | None = None, will_payload: str = "offline"):
    """A paho-mqtt client (MQTT 3.1.1) set up for ``url``: credentials, TLS, an unlimited
    outgoing queue (QoS 1 messages published while the broker is away wait in it and are
    sent, in order, when it is back), reconnect backoff 0.2-2 s, and the last will."""
    import paho.mqtt.client as mqtt  # the [fleet] extra

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id,
                         clean_session=clean_session, protocol=mqtt.MQTTv311)
    client.max_queued_messages_set(0)
    client.max_inflight_messages_set(100)
    client.reconnect_delay_set(min_delay=0.2, max_delay=2)
    if url.user:
        client.username_pw_set(url.user, url.password)
    if url.tls:
        for name, path in (("ca", url.ca), ("cert", url.cert), ("key", url.key)):
            if path and not os.path.isfile(path):
                raise FleetError(f"broker URL: {name} file {path} not found")
        context = ssl.create_default_context(cafile=url.ca)
        if url.cert:
            context.load_cert_chain(url.cert, url.key)
        if url.insecure:
            context.check_hostname = False
        client.tls_set_context(context)
    if will_topic:
        client.will_set(will_topic, will_payload, qos=1, retain=True)
    return client
