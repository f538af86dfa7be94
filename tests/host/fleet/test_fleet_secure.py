"""The fleet with broker authentication, an ACL and TLS (docs/fleet.md), PostgreSQL as the
store, and commands: only from named authenticated users, logged (issue 45)."""

from __future__ import annotations

import json
import shutil
import subprocess
import time

import pytest

pytest.importorskip("paho.mqtt.client")

from tests.fleet_support import PtyBox, wait_for  # noqa: E402
from thermal_comp.host.fleet.broker import make_client, parse_url  # noqa: E402
from thermal_comp.host.fleet.collector import Collector  # noqa: E402
from thermal_comp.host.fleet.export import export_run  # noqa: E402
from thermal_comp.host.fleet.gateway import Gateway  # noqa: E402
from thermal_comp.host.fleet.localrun import Mosquitto, Postgres, have_mosquitto, have_postgres  # noqa: E402
from thermal_comp.host.fleet.store import Store  # noqa: E402
from thermal_comp.host.fleet.topics import FleetError, command_topic  # noqa: E402

USERS = {"fleet": "fleet-pw", "gw-m1": "gw-pw", "alice": "alice-pw", "mallory": "mallory-pw"}
ACL = """user fleet
topic read thermalcomp/#
user gw-m1
topic readwrite thermalcomp/m1/#
pattern write thermalcomp/+/cmd/%u
"""


@pytest.fixture(scope="module")
def tls_broker(tmp_path_factory):
    if not have_mosquitto() or shutil.which("openssl") is None:
        pytest.skip("mosquitto or openssl not installed")
    d = tmp_path_factory.mktemp("tls")
    cert, key = d / "cert.pem", d / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
                    "-subj", "/CN=localhost", "-addext",
                    "subjectAltName=IP:127.0.0.1,DNS:localhost", "-keyout", str(key),
                    "-out", str(cert)], check=True, capture_output=True)
    b = Mosquitto(d / "broker", users=USERS, acl=ACL, tls=(str(cert), str(key))).start()
    b.ca = str(cert)
    yield b
    b.stop()


def _url(b, user: str, password: str | None = None) -> str:
    return (f"mqtts://{user}:{password or USERS[user]}@127.0.0.1:{b.port}?ca={b.ca}")


def _connect(url: str) -> int:
    """The CONNACK reason code value (0 accepted) or -1 when TLS fails."""
    import paho.mqtt.client as mqtt

    result: list[int] = []
    c = make_client(parse_url(url), f"probe-{time.monotonic_ns()}")
    c.on_connect = lambda cl, ud, fl, rc, pr: result.append(rc.value)
    try:
        c.connect("127.0.0.1", parse_url(url).port)
    except (OSError, mqtt.WebsocketConnectionError):
        return -1
    c.loop_start()
    try:
        wait_for(lambda: result, 5, "CONNACK")
    finally:
        c.disconnect()
        c.loop_stop()
    return result[0]


def test_the_broker_wants_a_password_and_tls(tls_broker):
    assert _connect(_url(tls_broker, "fleet")) == 0
    assert _connect(_url(tls_broker, "fleet", "wrong")) != 0
    anonymous = f"mqtts://127.0.0.1:{tls_broker.port}?ca={tls_broker.ca}"
    assert _connect(anonymous) != 0
    # plain MQTT to the TLS port, or TLS without trusting the self-signed CA: no connection
    import ssl

    with pytest.raises((ssl.SSLError, OSError)):
        c = make_client(parse_url(f"mqtts://fleet:fleet-pw@127.0.0.1:{tls_broker.port}"), "x")
        c.connect("127.0.0.1", tls_broker.port)


def test_commands_only_from_named_authenticated_users_and_logged(tls_broker, caplog):
    with pytest.raises(FleetError, match="authenticated"):
        Gateway("/dev/null", f"mqtt://127.0.0.1:{tls_broker.port}", "m1",
                allow_users=frozenset({"alice"}))
    box = PtyBox()
    gw = Gateway(box.path, _url(tls_broker, "gw-m1"), "m1", allow_users=frozenset({"alice"}))
    import threading

    t = threading.Thread(target=gw.run, kwargs={"duration": 8}, daemon=True)
    t.start()
    try:
        wait_for(lambda: gw.publisher.connected and "INFO" in box.commands, 5, "gateway up")
        time.sleep(0.3)  # the command subscription

        def send(user: str, command: str, as_topic_user: str | None = None) -> None:
            c = make_client(parse_url(_url(tls_broker, user)), f"{user}-{time.monotonic_ns()}")
            c.connect("127.0.0.1", tls_broker.port)
            c.loop_start()
            c.publish(command_topic("m1", as_topic_user or user),
                      json.dumps({"command": command, "t": time.time()}), qos=1
                      ).wait_for_publish(5)
            time.sleep(0.2)
            c.disconnect()
            c.loop_stop()

        send("mallory", "ZERO")  # authenticated, but not named for m1: refused, logged
        send("mallory", "ZERO", as_topic_user="alice")  # the ACL drops it at the broker
        send("alice", "ZERO")
        wait_for(lambda: "ZERO" in box.commands, 5, "alice's ZERO reaches the box")
        time.sleep(0.5)
        assert box.commands.count("ZERO") == 1
        log = gw.publisher.command_log
        assert ("mallory", "?", "refused: user 'mallory' may not command m1") in log
        assert ("alice", "ZERO", "accepted: sent to the box") in log
        assert len(log) == 2
        assert "command ZERO from user alice" in caplog.text
    finally:
        t.join(12)
        box.close()


def test_postgresql_store_through_an_authenticated_tls_broker(tls_broker):
    if not have_postgres():
        pytest.skip("PostgreSQL (initdb/pg_ctl) not installed")
    pytest.importorskip("psycopg")
    with Postgres() as pg:
        store = Store(pg.url)
        collector = Collector(_url(tls_broker, "fleet"), store, client_id="tc-fleet-pg")
        collector.start()
        wait_for(collector.connected.is_set, 5, "collector connected")
        box = PtyBox()
        gw = Gateway(box.path, _url(tls_broker, "gw-m1"), "m1")
        import threading

        t = threading.Thread(target=gw.run, kwargs={"count": 20}, daemon=True)
        t.start()
        try:
            wait_for(lambda: "INFO" in box.commands, 5, "INFO")
            time.sleep(0.3)
            for i in range(20):
                box.sample(status=0x0408 if i == 5 else 0, corr=(i * 10, -i * 20))
                time.sleep(0.01)
            t.join(15)
            wait_for(lambda: store.counts().get("m1") == 20, 10, "20 samples in PostgreSQL")
        finally:
            box.close()
            collector.stop()
        [m] = store.machines()
        assert m.extrap_n == 1 and m.clamp_n == 1 and m.model_hash == "a1b2c3d4"
        assert m.online is False  # the gateway said offline when it stopped
        import tempfile
        from pathlib import Path

        with tempfile.TemporaryDirectory() as d:
            done = export_run(store, "m1", 0, Path(d) / "run.csv")
            assert done.rows == 20
        store.close()


def test_sqlite_default_path_and_bad_urls(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path))
    monkeypatch.delenv("THERMALCOMP_FLEET_DB", raising=False)
    store = Store()
    assert (tmp_path / "thermalcomp" / "fleet.sqlite").is_file()
    store.close()
    for bad in ("http://x", "mqtt://", "mqtt://h:99999", "mqtt://h?ca=x", "mqtts://h?bogus=1"):
        with pytest.raises(FleetError):
            parse_url(bad)
    assert str(parse_url("mqtt://u:secret@h")) == "mqtt://u@h:1883"
    with pytest.raises(FleetError, match="database"):
        Store("postgresql://nobody@127.0.0.1:1/none")
