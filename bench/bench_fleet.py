"""Fleet load (issue 45): N simulated boxes at 1 Hz through a real mosquitto into the store,
a broker restart in the middle, the page fetched while it runs.

    python -m bench fleet             # 200 boxes, 10 minutes (python -m bench fleet --quick: 30 s)
    python -m bench.bench_fleet --boxes 200 --minutes 10 [--db postgresql] [--quick]

Each box is what a gateway is (host.fleet.gateway's Translator and Publisher: its own MQTT
connection, last will, QoS 1, retained state) fed with encoded protocol lines instead of a
serial port. The service is host.fleet.collector into SQLite (or a throw-away PostgreSQL).
Writes bench/results/fleet.json: boxes, messages, lost, store latency p50/p99 (publish to
commit), page_ms_p99, the restart's down time.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

from bench.goal import INFO as INFO_ROW
from bench.goal import goal
from thermal_comp.contract import protocol

RESULTS = Path(__file__).parent / "results" / "fleet.json"
INFO = protocol.Info("1.4.0", "a1b2c3d4", True, 1000, ("dx_um", "dy_um", "dz_um"),
                     tuple(protocol.Channel(i, f"T{i + 1:02d}", "K") for i in range(8)))


def _pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def bench(boxes: int = 200, seconds: float = 600.0, db: str = "sqlite",
          restart_down_s: float = 3.0, workdir: str | None = None) -> dict:
    from thermal_comp.host.fleet.collector import Collector
    from thermal_comp.host.fleet.gateway import Publisher, Translator
    from thermal_comp.host.fleet.localrun import Mosquitto, Postgres
    from thermal_comp.host.fleet.store import Store
    from thermal_comp.host.fleet.web import make_server

    logging.basicConfig(level=logging.ERROR)
    work = Path(workdir or tempfile.mkdtemp(prefix="bench-fleet-"))
    broker = Mosquitto(work / "broker").start()
    pg = Postgres().start() if db == "postgresql" else None
    url = pg.url if pg else f"sqlite:///{work / 'fleet.sqlite'}"
    store = Store(url)
    collector = Collector(broker.url, store, client_id="bench-fleet")
    collector.start()
    server = make_server(url, 0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    page_url = f"http://127.0.0.1:{server.server_address[1]}/"

    gws = [Translator(f"box{i:03d}") for i in range(boxes)]
    pubs = [Publisher(broker.url, g.machine, g.gateway_id) for g in gws]
    for p in pubs:
        p.start()
    t0 = time.time()
    for g, p in zip(gws, pubs, strict=True):
        for kind, msg in g.line(protocol.encode_info(INFO), t0):
            p.publish(kind, msg)
    page_ms: list[float] = []
    stop_pages = threading.Event()

    def fetch_pages() -> None:
        while not stop_pages.wait(5.0):
            t = time.perf_counter()
            try:
                urllib.request.urlopen(page_url, timeout=30).read()
                page_ms.append((time.perf_counter() - t) * 1000)
            except OSError:
                page_ms.append(float("inf"))

    pager = threading.Thread(target=fetch_pages, daemon=True)
    pager.start()
    sent = 0
    n_ticks = int(seconds)
    restart_at = n_ticks // 2
    restarted_at = down = None
    start = time.monotonic()
    for tick in range(n_ticks):
        if tick == restart_at:
            restarted_at = time.time()
            threading.Thread(target=broker.restart, args=(restart_down_s,), daemon=True).start()
        for i, (g, p) in enumerate(zip(gws, pubs, strict=True)):
            # spread the boxes over the second, as real ones are
            target = start + tick + i / boxes
            delay = target - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            status = 0x0400 if (tick + i) % 97 == 0 else 0
            line = protocol.encode_sample(tick, status, (tick * 7 + i, -tick * 3, i),
                                          tuple(2560 + (tick + i + c) % 50 for c in range(8)))
            for kind, msg in g.line(line, time.time()):
                p.publish(kind, msg)
                sent += kind == "state"
    publish_end = time.time()
    if restarted_at is not None:
        down = restart_down_s
    for p in pubs:
        p.stop(timeout_s=60)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and sum(store.counts().values()) < sent:
        time.sleep(0.5)
    drain_s = time.time() - publish_end
    stop_pages.set()
    pager.join(10)
    for _ in range(5):  # the page once more with everything in
        t = time.perf_counter()
        urllib.request.urlopen(page_url, timeout=30).read()
        page_ms.append((time.perf_counter() - t) * 1000)
    stored = sum(store.counts().values())
    pairs = store.latencies()
    lat = [d for _, d in pairs]
    # outside the restart: samples published before it or 10 s after the broker was back
    back = (restarted_at or 0) + restart_down_s + 10
    outside = [d for t, d in pairs if restarted_at is None or t < restarted_at or t > back]
    result = {
        "boxes": boxes, "seconds": n_ticks, "rate_hz": 1.0, "db": db,
        "messages": sent, "stored": stored, "lost": sent - stored,
        "refused": collector.refused,
        "store_latency_p50_s": round(_pct(lat, 0.50), 4),
        "store_latency_p99_s": round(_pct(lat, 0.99), 4),
        "store_latency_p99_outside_restart_s": round(_pct(outside, 0.99), 4),
        "page_ms_p50": round(_pct(page_ms, 0.50), 1),
        "page_ms_p99": round(_pct(page_ms, 0.99), 1), "page_fetches": len(page_ms),
        "broker_restart_down_s": down, "drain_after_end_s": round(drain_s, 1),
        "machine": platform.platform(), "cpus": os.cpu_count(),
    }
    collector.stop()
    server.shutdown()
    store.close()
    broker.stop()
    if pg:
        pg.stop()
    return result


def _table(r: dict) -> str:
    rows = [("boxes", r["boxes"], f"at 1 Hz for {r['seconds']} s"),
            ("messages", r["messages"], "states published (QoS 1)"),
            ("lost", r["lost"], "target 0, with a broker restart in the middle"),
            ("store latency p50", r["store_latency_p50_s"], "s, publish to commit"),
            ("store latency p99", r["store_latency_p99_s"], "s (all samples, the restart's too)"),
            ("  p99 outside the restart", r["store_latency_p99_outside_restart_s"], "s"),
            ("page_ms_p99", r["page_ms_p99"], f"ms over {r['page_fetches']} fetches, "
             "target < 1000")]
    return "\n".join(f"  {a:<28} {b!s:>10}  {c}" for a, b, c in rows)


RUNNER_FLAGS = ("--quick",)  # python -m bench fleet --quick (bench/__main__.py passes it on)


def run(flags: tuple[str, ...] | list[str] = ()) -> list[dict]:
    """For ``python -m bench``: 200 boxes for 10 minutes, or 30 s with ``--quick``."""
    quick = "--quick" in flags
    r = bench(200, 30.0 if quick else 600.0)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(r, indent=2) + "\n")
    print(_table(r))
    return [
        {"name": "fleet boxes through mosquitto", "value": r["boxes"], "unit": "boxes",
         "goal": INFO_ROW,
         "detail": f"{r['seconds']} s at 1 Hz"},
        {"name": "fleet messages lost (broker restart)", "value": r["lost"], "unit": "msgs",
         "target": "0", "goal": goal("==", 0), "detail": f"of {r['messages']}"},
        {"name": "fleet store latency p99", "value": r["store_latency_p99_s"], "unit": "s",
         "goal": INFO_ROW},
        {"name": "fleet page p99", "value": r["page_ms_p99"], "unit": "ms",
         "target": "< 1000", "goal": goal("<", 1000)},
    ]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--boxes", type=int, default=200)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--quick", action="store_true", help="30 s")
    ap.add_argument("--db", choices=("sqlite", "postgresql"), default="sqlite")
    ap.add_argument("-o", "--output", type=Path, default=RESULTS)
    args = ap.parse_args()
    r = bench(args.boxes, 30.0 if args.quick else args.minutes * 60, args.db)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(r, indent=2) + "\n")
    print(_table(r))
    print(f"wrote {args.output}")
    return 0 if r["lost"] == 0 and r["page_ms_p99"] < 1000 else 1


if __name__ == "__main__":
    raise SystemExit(main())
