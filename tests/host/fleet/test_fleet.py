"""The fleet over a real mosquitto (issue 45): gateway -> broker -> collector -> SQLite, a
broker restart mid-stream, the last will, bad input, status, the page, export."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

pytest.importorskip("paho.mqtt.client")

from tests.fleet_support import INFO, PtyBox, wait_for  # noqa: E402
from thermal_comp.contract import protocol  # noqa: E402
from thermal_comp.host.cli import main as host_main  # noqa: E402
from thermal_comp.host.fleet.collector import Collector  # noqa: E402
from thermal_comp.host.fleet.export import export_run, parse_since  # noqa: E402
from thermal_comp.host.fleet.gateway import Publisher, Translator, parse_command  # noqa: E402
from thermal_comp.host.fleet.localrun import Mosquitto, have_mosquitto  # noqa: E402
from thermal_comp.host.fleet.spool import Spool  # noqa: E402
from thermal_comp.host.fleet.store import Store  # noqa: E402
from thermal_comp.host.fleet.topics import (  # noqa: E402
    MAX_PAYLOAD,
    FleetError,
    Refused,
    encode,
    parse,
    topic,
)
from thermal_comp.host.fleet.web import make_server, render_fleet  # noqa: E402
from thermal_comp.host.io import load_run  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
needs_broker = pytest.mark.skipif(not have_mosquitto(), reason="mosquitto not installed "
                                  "(scripts/install-system-deps.sh installs it)")


@pytest.fixture(scope="module")
def broker(tmp_path_factory):
    if not have_mosquitto():
        pytest.skip("mosquitto not installed")
    b = Mosquitto(tmp_path_factory.mktemp("mosquitto")).start()
    yield b
    b.stop()


def _publish_raw(url_port: int, topic_name: str, payload: bytes) -> None:
    import paho.mqtt.client as mqtt

    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"raw-{time.monotonic_ns()}")
    c.connect("127.0.0.1", url_port)
    c.loop_start()
    c.publish(topic_name, payload, qos=1).wait_for_publish(5)
    c.disconnect()
    c.loop_stop()


# ---- no broker ----------------------------------------------------------------------------
def test_translator_names_samples_and_tolerates_new_lines():
    tr = Translator("mill-1", "gw")
    now = 1_700_000_000.0
    [(kind, info)] = tr.line(protocol.encode_info(INFO), now)
    assert kind == "event" and info["event"] == "info" and info["model_hash"] == "a1b2c3d4"
    [(kind, s)] = tr.line(protocol.encode_sample(7, 0x0408, (1500, -2500), (2560, 2688)), now)
    assert kind == "state"
    assert s["seq"] == 7 and s["flags"] == ["CLAMP", "EXTRAP"] and s["status"] == "0408"
    assert s["corrections_um"] == {"dx_um": 1.5, "dz_um": -2.5}
    assert s["temperatures_c"] == {"T01": 20.0, "T02": 21.0}
    assert s["model_hash"] == "a1b2c3d4" and s["n"] == 2
    parse(topic("mill-1", "state"), encode(s))  # what it sends, the service accepts
    # a future MEAS answer: published as a probe event, its innovation the last residual
    [(kind, ev)] = tr.line(protocol.encode_line("OK", ["MEAS", "dz_um", -800, 1, "OK", 20, 9]),
                           now)
    assert ev["event"] == "probe" and ev["residual_um"] == {"dz_um": -0.8}
    [(_, s2)] = tr.line(protocol.encode_sample(8, 0, (0, 0), (1, 1)), now)
    assert s2["probe"]["residual_um"] == {"dz_um": -0.8}
    # the firmware's $M answer (issue 42): axis, seq, A|R, reason, innovation nm, ...
    [(_, ev)] = tr.line(protocol.encode_line("M", ["dx_um", 8, "A", "-", 1200, 300, 40]), now)
    assert ev["event"] == "probe" and ev["residual_um"] == {"dx_um": 1.2}
    # an unknown kind with a good CRC: passed on, not an error
    [(_, ev)] = tr.line(protocol.encode_line("X", ["1", "2"]), now)
    assert ev["event"] == "unknown_line" and "'X'" in ev["message"]
    # a corrupted line: a bad_line event, at most one a second, with the count
    bad = protocol.encode_sample(9, 0, (0, 0), (1, 1)).replace(b"$C,9", b"$C,8")
    [(_, ev)] = tr.line(bad, now)
    assert ev["event"] == "bad_line" and "CRC" in ev["message"]
    assert tr.line(bad, now + 0.1) == []
    [(_, ev)] = tr.line(bad, now + 1.2)
    assert ev["count"] == 2 and ev["total"] == 3
    # another model after reconnecting: flagged
    other = protocol.Info("1.4.0", "ffff0000", True, 1000, INFO.axes, INFO.channels)
    kinds = [m["event"] for _, m in tr.line(protocol.encode_info(other), now)]
    assert kinds == ["info", "model_changed"]


def test_the_service_refuses_bad_messages_with_a_reason():
    good = {"schema": 1, "machine": "m1", "gateway": "g", "n": 1, "t": 1.7e9, "seq": 1,
            "status": "0000", "flags": [], "corrections_um": {"dz_um": 1.0},
            "temperatures_c": {"T01": 20.0}, "faults": {}, "model_hash": "ab"}
    assert parse("thermalcomp/m1/state", encode(good)).data["seq"] == 1
    cases = [
        ("thermalcomp/m1/state", b"{not json", "malformed JSON"),
        ("thermalcomp/m1/state", b"x" * (MAX_PAYLOAD + 1), "oversized"),
        ("thermalcomp/m2/state", encode(good), "names machine 'm1'"),
        ("thermalcomp/m1/weird", encode(good), "unknown topic kind"),
        ("thermalcomp/m 1/state", encode(good), "not a valid name"),
        ("thermalcomp/m1/state", encode({**good, "seq": -1}), "seq -1"),
        ("thermalcomp/m1/state", encode({**good, "corrections_um": {"dz_um": "1"}}),
         "not a number"),
        ("thermalcomp/m1/state", b'{"schema":1,"machine":"m1","n":1e999}', "not finite"),
        ("thermalcomp/m1/online", b"maybe", "not online/offline"),
    ]
    for t, payload, reason in cases:
        with pytest.raises(Refused, match=reason.replace("(", r"\(")):
            parse(t, payload)
    assert parse("thermalcomp/m1/cmd/alice", b"ZERO") is None  # not the service's business


def test_commands_must_be_fresh_and_known():
    now = 1_700_000_000.0
    assert parse_command(json.dumps({"command": "ZERO", "t": now}).encode(), now) == (
        "ZERO", b"ZERO\r\n")
    assert parse_command(b'{"command": "RATE 5", "t": 1700000000}', now)[1] == b"RATE 5\r\n"
    for payload, why in [(b"ZERO", "not JSON"), (b'{"command": "ZERO"}', "no \"t\""),
                         (json.dumps({"command": "ZERO", "t": now - 60}).encode(), "ago"),
                         (b'{"command": "REBOOT", "t": 1700000000}', "not one of"),
                         (b'{"command": "RATE x", "t": 1700000000}', "bad argument")]:
        with pytest.raises(ValueError, match=why):
            parse_command(payload, now)


def test_the_spool_keeps_what_is_not_acknowledged_and_recovers_it_in_order(tmp_path,
                                                                           monkeypatch):
    import thermal_comp.host.fleet.spool as spool_mod

    path = tmp_path / "state" / "spool-m1.jsonl"
    sp = Spool(path, fsync=False)
    assert sp.recovered == []
    msgs = [{"gateway": "g1", "n": i, "seq": i} for i in range(1, 6)]
    for m in msgs:
        sp.add(spool_mod.message_key(m), "state", m)
    sp.ack("g1:1")
    sp.ack("g1:3")
    sp.close()  # the gateway killed: 2, 4 and 5 never acknowledged
    with path.open("a") as fh:
        fh.write('{"key": "g1:6", "kind": "sta')  # a line the kill cut short
    sp = Spool(path, fsync=False)
    assert [d["n"] for _, d in sp.recovered] == [2, 4, 5]
    for n in (2, 4, 5):
        sp.ack(f"g1:{n}")
    assert path.stat().st_size == 0 and sp.pending() == 0  # nothing open: truncated
    # a long outage's ack lines are compacted away once they outnumber the open messages
    monkeypatch.setattr(spool_mod, "COMPACT_ACKS", 3)
    for n in range(10, 16):
        sp.add(f"g2:{n}", "event", {"gateway": "g2", "n": n})
    for n in range(10, 15):
        sp.ack(f"g2:{n}")
    sp.close()
    assert len(path.read_text().splitlines()) == 1  # 6 messages and 5 acks compacted to 1
    assert [d["n"] for _, d in Spool(path).recovered] == [15]
    assert spool_mod.default_spool_path("m1").name == "spool-m1.jsonl"


# ---- through the broker ------------------------------------------------------------------
@needs_broker
def test_nothing_is_lost_across_a_broker_restart(broker, tmp_path):
    store = Store(f"sqlite:///{tmp_path / 'fleet.sqlite'}")
    collector = Collector(broker.url, store, client_id="tc-fleet-restart")
    collector.start()
    wait_for(collector.connected.is_set, what="collector connected")
    boxes = [Translator(f"m{i}") for i in range(3)]
    pubs = [Publisher(broker.url, b.machine, b.gateway_id) for b in boxes]
    for p in pubs:
        p.start()
    now = time.time()
    for b, p in zip(boxes, pubs, strict=True):
        for kind, msg in b.line(protocol.encode_info(INFO), now):
            p.publish(kind, msg)
    n = 120
    for seq in range(n):
        if seq == 40:
            broker.stop()  # mid-stream: the gateways queue, the broker keeps the session
        if seq == 80:
            broker.start()
        for b, p in zip(boxes, pubs, strict=True):
            for kind, msg in b.line(protocol.encode_sample(seq, 0x0400 * (seq % 10 == 0),
                                                           (seq, -seq), (2560, 2600)),
                                    time.time()):
                p.publish(kind, msg)
        time.sleep(0.004)
    wait_for(lambda: store.counts() == {f"m{i}": n for i in range(3)}, 20,
             "every sample stored")
    for p in pubs:
        p.stop()
    wait_for(lambda: all(m.status(time.time()) == "offline" for m in store.machines()), 10,
             "offline after stop")
    rows = {m.name: m for m in store.machines()}
    assert rows["m1"].samples_n == n and rows["m1"].extrap_n == 12
    assert rows["m1"].state["seq"] == n - 1 and rows["m1"].model_hash == "a1b2c3d4"
    collector.stop()


@needs_broker
def test_host_gateway_on_a_pty_its_last_will_and_fleet_status(broker, tmp_path):
    db = f"sqlite:///{tmp_path / 'fleet.sqlite'}"
    store = Store(db)
    collector = Collector(broker.url, store, client_id="tc-fleet-gw")
    collector.start()
    box = PtyBox()
    gw = subprocess.Popen([sys.executable, "-m", "thermal_comp.host", "gateway", box.path, "--mqtt",
                           broker.url, "--machine", "lathe-2", "--spool",
                           str(tmp_path / "spool.jsonl")], cwd=ROOT,
                          stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: "INFO" in box.commands, 10, "the gateway asks INFO")
        time.sleep(0.3)
        for _ in range(5):
            box.sample()
        box.sample(status=0x0022)  # HOLD + OPEN: the gateway asks STATUS, names T01
        wait_for(lambda: "STATUS" in box.commands, 5, "STATUS asked")
        time.sleep(0.3)
        box.sample(status=0x0022)
        box.send(b"$C,garbage*0000\r\n")
        wait_for(lambda: (store.machines() and store.machines()[0].samples_n == 7), 10,
                 "7 samples stored")
        m = store.machines()[0]
        assert m.name == "lathe-2" and m.online is True and m.status(time.time()) == "online"
        assert m.state["faults"] == {"T01": ["OPEN"]} and m.state["temperatures_c"]["T01"] is None
        assert m.state["corrections_um"] == {"dx_um": 1.5, "dz_um": -2.5}
        wait_for(lambda: store.events(kinds=["bad_line"]), 5, "the bad line reported")
        gw.send_signal(signal.SIGKILL)  # no goodbye: the broker publishes its last will
        gw.wait(5)
        wait_for(lambda: store.machines()[0].online is False, 10, "last will: offline")
    finally:
        if gw.poll() is None:
            gw.kill()
        box.close()
        collector.stop()
    out = subprocess.run([sys.executable, "-m", "thermal_comp.host", "fleet", "status", "--db", db],
                         cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith("lathe-2"))
    assert "offline" in line and "T01:OPEN" in line and "a1b2c3d4" in line


@needs_broker
def test_bad_input_is_refused_flagged_and_never_stops_the_service(broker, tmp_path):
    store = Store(f"sqlite:///{tmp_path / 'fleet.sqlite'}")
    collector = Collector(broker.url, store, machines={"press-1": "a1b2c3d4"},
                          client_id="tc-fleet-bad")
    collector.start()
    wait_for(collector.connected.is_set, what="connected")
    tr = Translator("press-1", "gw1")
    msgs = tr.line(protocol.encode_info(INFO), time.time())
    msgs += tr.line(protocol.encode_sample(0, 0, (10, 20), (2560, 2600)), time.time())
    for kind, m in msgs:
        _publish_raw(broker.port, topic("press-1", kind), encode(m))
    _publish_raw(broker.port, "thermalcomp/press-1/state", b"{oops")
    _publish_raw(broker.port, "thermalcomp/press-1/state", b"[" * (MAX_PAYLOAD + 10))
    stranger = Translator("stranger", "gw2")
    [(k, m)] = stranger.line(protocol.encode_sample(0, 0, (1,), (1,)), time.time())
    _publish_raw(broker.port, topic("stranger", k), encode(m))
    # the box comes back with another model: stored, and flagged
    other = protocol.Info("1.4.0", "deadbeef", True, 1000, INFO.axes, INFO.channels)
    for kind, m in (tr.line(protocol.encode_info(other), time.time())
                    + tr.line(protocol.encode_sample(1, 0, (11, 21), (2561, 2601)),
                              time.time())):
        _publish_raw(broker.port, topic("press-1", kind), encode(m))
    # (the retained states of the other tests' machines are refused too: unknown here)
    wait_for(lambda: store.machines()[0].samples_n == 2 and any(
        "stranger" in r[3] for r in store.refusals()), 10, "2 samples and the stranger refused")
    reasons = [r[3] for r in store.refusals()]
    assert any("malformed JSON" in r for r in reasons)
    assert any("oversized" in r for r in reasons)
    assert any("unknown machine 'stranger'" in r for r in reasons)
    [m] = store.machines()
    assert "model hash changed from a1b2c3d4 to deadbeef" in m.flag
    assert "the fleet expects a1b2c3d4" in m.flag
    html = render_fleet(store)
    for text in ("malformed JSON", "oversized", "unknown machine", "model hash changed"):
        assert text in html
    assert collector.client.is_connected()
    collector.stop()


def _gateway(box: PtyBox, url: str, machine: str, spool: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "thermal_comp.host", "gateway", box.path,
                             "--mqtt", url,
                             "--machine", machine, "--spool", str(spool)], cwd=ROOT,
                            stderr=subprocess.PIPE, text=True)


def _spooled(path: Path) -> dict[str, dict]:
    """The spool's open messages (key -> data), read as the next gateway will."""
    out: dict[str, dict] = {}
    for line in path.read_text().splitlines() if path.exists() else []:
        rec = json.loads(line)
        if "ack" in rec:
            out.pop(rec["ack"], None)
        else:
            out[rec["key"]] = rec["data"]
    return out


@needs_broker
def test_a_gateway_killed_during_an_outage_loses_nothing_with_its_spool(broker, tmp_path):
    """Broker down, samples published, the gateway killed (SIGKILL: no goodbye), broker and
    gateway started again: every sample is in the store exactly once."""
    store = Store(f"sqlite:///{tmp_path / 'fleet.sqlite'}")
    collector = Collector(broker.url, store, client_id="tc-fleet-spool")
    collector.start()
    wait_for(collector.connected.is_set, what="collector connected")
    box, spool = PtyBox(), tmp_path / "spool-drill-3.jsonl"
    gw = _gateway(box, broker.url, "drill-3", spool)
    try:
        wait_for(lambda: "INFO" in box.commands, 10, "the gateway asks INFO")
        time.sleep(0.3)
        for _ in range(5):
            box.sample()
        wait_for(lambda: store.counts().get("drill-3") == 5, 10, "5 samples stored")
        wait_for(lambda: spool.exists() and spool.stat().st_size == 0, 5,
                 "the spool emptied once all was acknowledged")
        broker.stop()
        for _ in range(10):  # seq 5..14: queued, and on disk
            box.sample()
        wait_for(lambda: sorted(d["seq"] for d in _spooled(spool).values() if "seq" in d)
                 == list(range(5, 15)), 10, "the outage's 10 samples in the spool")
        gw.send_signal(signal.SIGKILL)
        gw.wait(5)
        # a second gateway on the same spool while one runs would be refused
        held = Spool(spool)
        with pytest.raises(FleetError, match="in use"):
            Spool(spool)
        held.close()
        broker.start()
        gw = _gateway(box, broker.url, "drill-3", spool)
        wait_for(lambda: box.commands.count("INFO") >= 2, 10, "the new gateway asks INFO")
        time.sleep(0.3)
        for _ in range(3):  # seq 15..17, from the new gateway
            box.sample()
        wait_for(lambda: store.counts().get("drill-3") == 18, 15, "all 18 samples stored")
        time.sleep(0.5)  # anything sent twice would have arrived by now
        rows = store.samples("drill-3")
        assert sorted(r["seq"] for r in rows) == list(range(18))  # each once
        assert len({r["gateway"] for r in rows}) == 2  # the outage's under the first run's id
        wait_for(lambda: spool.stat().st_size == 0, 5, "the spool empty again")
    finally:
        if gw.poll() is None:
            gw.terminate()
            gw.wait(15)
        box.close()
        collector.stop()
        if broker.proc is None:
            broker.start()


@needs_broker
def test_host_monitor_mqtt_publishes_what_the_gateway_would(broker, tmp_path):
    store = Store(f"sqlite:///{tmp_path / 'fleet.sqlite'}")
    collector = Collector(broker.url, store, client_id="tc-fleet-monitor")
    collector.start()
    wait_for(collector.connected.is_set, what="collector connected")
    box = PtyBox()
    mon = subprocess.Popen([sys.executable, "-m", "thermal_comp.host", "monitor", box.path,
                            "--plain",
                            "--count", "4", "--duration", "20", "--mqtt", broker.url,
                            "--machine", "mill-9", "--spool", str(tmp_path / "spool.jsonl")],
                           cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    sent: list[bytes] = []
    try:
        wait_for(lambda: "INFO" in box.commands, 10, "the monitor asks INFO")
        time.sleep(0.3)
        for status in (0, 0, 0x0022, 0x0022):  # HOLD + OPEN: STATUS names T01
            line = protocol.encode_sample(box.seq, status, (1500, -2500), (2600, 2700))
            sent.append(line)
            box.sample(status=status)
            if status:
                wait_for(lambda: "STATUS" in box.commands, 5, "STATUS asked")
                time.sleep(0.3)
        out, err = mon.communicate(timeout=30)
    finally:
        if mon.poll() is None:
            mon.kill()
        box.close()
    assert mon.returncode == 0, err
    assert "seq=3" in out and "T01=FAULT(OPEN)" in out  # the screen's (plain) view
    wait_for(lambda: store.counts().get("mill-9") == 4, 10, "4 samples stored")
    # the same lines through the gateway's translator: the same states
    tr = Translator("mill-9", "g")
    tr.line(protocol.encode_info(INFO), 0.0)
    status = protocol.encode_status(protocol.StatusReport(0x22, 3, 10, (0x0001, 0), None))
    expect = [tr.line(sent[0], 0.0), tr.line(sent[1], 0.0), tr.line(sent[2], 0.0),
              tr.line(status, 0.0), tr.line(sent[3], 0.0)]
    states = [m for batch in expect for kind, m in batch if kind == "state"]
    rows = store.samples("mill-9")
    keys = ("seq", "status", "flags", "model_hash", "period_ms", "corrections_um",
            "temperatures_c")
    assert [{k: r[k] for k in keys} for r in rows] == [{k: s[k] for k in keys} for s in states]
    def mill9():  # (the other tests' machines come as retained states)
        return next(m for m in store.machines() if m.name == "mill-9")

    assert mill9().state["faults"] == {"T01": ["OPEN"]}
    wait_for(lambda: mill9().online is False, 10, "offline when it stops")
    collector.stop()


# ---- the page, export ---------------------------------------------------------------------
def _filled_store(path: Path) -> Store:
    store = Store(f"sqlite:///{path}")
    from thermal_comp.host.fleet.topics import Message

    tr = Translator("mill-7", "g")
    t0 = time.time() - 3600
    tr.line(protocol.encode_info(INFO), t0)
    for seq in range(0, 600):
        lines = [protocol.encode_sample(seq, 0, (seq * 3, -seq * 5), (2560 + seq, 2600))]
        if seq == 300:
            lines.insert(0, protocol.encode_line("OK", ["MEAS", "dz_um", -700, 1, "OK", 5, 9]))
        if seq in (101, 102):
            continue  # two lost lines
        for kind, m in [m for line in lines for m in tr.line(line, t0 + seq * 6)]:
            store.add(Message("mill-7", kind, m), now=t0 + seq * 6 + 0.01)
    return store


def test_export_writes_a_run_the_loader_reads(tmp_path):
    store = _filled_store(tmp_path / "f.sqlite")
    done = export_run(store, "mill-7", 0, tmp_path / "run.csv")
    assert done.rows == 600 and done.missing_rows == 2 and done.probes == 1
    run = load_run(tmp_path / "run.csv", ["corr_dz_um"], sensors="T*", fill_gaps=2)
    assert run.sensor_names == ["T01", "T02"] and run.n_samples == 600 and run.filled_cells
    assert run.time_s[1] - run.time_s[0] == 1.0  # seq x period, not the arrival time
    header = (tmp_path / "run.csv").read_text().splitlines()[0].split(",")
    assert header == ["time_s", "T01", "T02", "corr_dx_um", "corr_dz_um", "probe_dz_um"]
    assert abs(parse_since("2h", 10_000.0) - 2_800.0) < 1e-9
    rc = host_main(["fleet", "export", "nope", "--db", f"sqlite:///{tmp_path / 'f.sqlite'}",
                    "-o", str(tmp_path / "x.csv")])
    assert rc == 2


def test_the_page_is_read_only_and_shows_the_day(tmp_path):
    store = _filled_store(tmp_path / "f.sqlite")
    server = make_server(store.url, 0)
    port = server.server_address[1]
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        t0 = time.perf_counter()
        page = urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5).read().decode()
        assert time.perf_counter() - t0 < 1.0
        assert "mill-7" in page and "<polyline" in page and "<circle" in page
        assert "dz_um -0.70 µm" in page  # the last probe residual
        detail = urllib.request.urlopen(f"http://127.0.0.1:{port}/machine/mill-7",
                                        timeout=5).read().decode()
        assert "probe answer" in detail
        status = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/status.json",
                                                   timeout=5).read())
        assert status[0]["machine"] == "mill-7" and status[0]["status"] == "stale"
        req = urllib.request.Request(f"http://127.0.0.1:{port}/", data=b"x", method="POST")
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(req, timeout=5)
        assert err.value.code == 405
        chromium = shutil.which("chromium") or shutil.which("chromium-browser")
        if chromium:
            shot = tmp_path / "page.png"
            proc = subprocess.run(
                [chromium, "--headless", "--no-sandbox", "--disable-gpu",
                 "--window-size=1400,700", f"--screenshot={shot}",
                 f"http://127.0.0.1:{port}/"], capture_output=True, timeout=60,
                env={**os.environ, "HOME": str(tmp_path)})
            assert proc.returncode == 0 and shot.stat().st_size > 10_000, proc.stderr[-500:]
    finally:
        server.shutdown()
