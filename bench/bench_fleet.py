"""Fleet load (issue 45): N simulated boxes at 1 Hz through a real mosquitto into the store,
a broker restart in the middle, the page fetched while it runs.

    python -m bench fleet             # 200 boxes, 10 minutes (python -m bench fleet --quick: 30 s)
    python -m bench.bench_fleet --boxes 200 --minutes 10 [--db postgresql] [--quick]

Each box is what a gateway is (host.fleet's Translator and Publisher: its own MQTT
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
from typing import TYPE_CHECKING

from bench.goal import INFO as INFO_ROW
from bench.goal import goal
from thermal_comp.contract import protocol

if TYPE_CHECKING:  # the fleet's modules need paho; imported when the bench runs
    from thermal_comp.host.fleet.localrun import Mosquitto
    from thermal_comp.host.fleet.publisher import Publisher
    from thermal_comp.host.fleet.translator import Translator

RESULTS = Path(__file__).parent / "results" / "fleet.json"
INFO = protocol.Info("1.4.0", "a1b2c3d4", True, 1000, ("dx_um", "dy_um", "dz_um"),
                     tuple(protocol.Channel(i, f"T{i + 1:02d}", "K") for i in range(8)))


def _pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


class Service:
    """The fleet's service side as it runs in a shop: the broker, the collector into the
    store (SQLite, or a throw-away PostgreSQL) and the page, started in that order."""

    def __init__(self, work: Path, db: str) -> None:
        from thermal_comp.host.fleet.collector import Collector
        from thermal_comp.host.fleet.localrun import Mosquitto, Postgres
        from thermal_comp.host.fleet.store import Store
        from thermal_comp.host.fleet.web import make_server

        self.broker = Mosquitto(work / "broker").start()
        self.pg = Postgres().start() if db == "postgresql" else None
        url = self.pg.url if self.pg else f"sqlite:///{work / 'fleet.sqlite'}"
        self.store = Store(url)
        self.collector = Collector(self.broker.url, self.store, client_id="bench-fleet")
        self.collector.start()
        self.server = make_server(url, 0)
        threading.Thread(target=self.server.serve_forever, daemon=True).start()
        self.page_url = f"http://127.0.0.1:{self.server.server_address[1]}/"

    def stop(self) -> None:
        self.collector.stop()
        self.server.shutdown()
        self.store.close()
        self.broker.stop()
        if self.pg:
            self.pg.stop()


class PageTimer:
    """The page fetched every 5 s while the boxes publish, as a shop's screen would: each
    fetch's milliseconds (inf for one that failed)."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.ms: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._fetch_pages, daemon=True)
        self._thread.start()

    def _fetch_pages(self) -> None:
        while not self._stop.wait(5.0):
            t = time.perf_counter()
            try:
                urllib.request.urlopen(self.url, timeout=30).read()
                self.ms.append((time.perf_counter() - t) * 1000)
            except OSError:
                self.ms.append(float("inf"))

    def stop(self, final_fetches: int = 5) -> None:
        """Stop the timer, then fetch the page ``final_fetches`` times with everything in."""
        self._stop.set()
        self._thread.join(10)
        for _ in range(final_fetches):
            t = time.perf_counter()
            urllib.request.urlopen(self.url, timeout=30).read()
            self.ms.append((time.perf_counter() - t) * 1000)


def publish(gws: list[Translator], pubs: list[Publisher], broker: Mosquitto, n_ticks: int,
            restart_down_s: float) -> tuple[int, float | None]:
    """Every box's sample once a second for ``n_ticks`` seconds, the boxes spread over each
    second as real ones are, the broker restarted half-way: (states sent, when it restarted)."""
    boxes = len(gws)
    sent = 0
    restart_at = n_ticks // 2
    restarted_at = None
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
    return sent, restarted_at


def bench(boxes: int = 200, seconds: float = 600.0, db: str = "sqlite",
          restart_down_s: float = 3.0, workdir: str | None = None) -> dict:
    """``boxes`` gateways publishing for ``seconds`` through a broker restarted half-way into
    the service: what was lost, how late it was stored, how fast the page came."""
    from thermal_comp.host.fleet.publisher import Publisher
    from thermal_comp.host.fleet.translator import Translator

    logging.basicConfig(level=logging.ERROR)
    work = Path(workdir or tempfile.mkdtemp(prefix="bench-fleet-"))
    service = Service(work, db)
    gws = [Translator(f"box{i:03d}") for i in range(boxes)]
    pubs = [Publisher(service.broker.url, g.machine, g.gateway_id) for g in gws]
    for p in pubs:
        p.start()
    t0 = time.time()
    for g, p in zip(gws, pubs, strict=True):
        for kind, msg in g.line(protocol.encode_info(INFO), t0):
            p.publish(kind, msg)
    pages = PageTimer(service.page_url)
    n_ticks = int(seconds)
    sent, restarted_at = publish(gws, pubs, service.broker, n_ticks, restart_down_s)
    publish_end = time.time()
    down = restart_down_s if restarted_at is not None else None
    for p in pubs:
        p.stop(timeout_s=60)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and sum(service.store.counts().values()) < sent:
        time.sleep(0.5)
    drain_s = time.time() - publish_end
    pages.stop()
    stored = sum(service.store.counts().values())
    pairs = service.store.latencies()
    lat = [d for _, d in pairs]
    # outside the restart: samples published before it or 10 s after the broker was back
    back = (restarted_at or 0) + restart_down_s + 10
    outside = [d for t, d in pairs if restarted_at is None or t < restarted_at or t > back]
    result = {
        "boxes": boxes, "seconds": n_ticks, "rate_hz": 1.0, "db": db,
        "messages": sent, "stored": stored, "lost": sent - stored,
        "refused": service.collector.refused,
        "store_latency_p50_s": round(_pct(lat, 0.50), 4),
        "store_latency_p99_s": round(_pct(lat, 0.99), 4),
        "store_latency_p99_outside_restart_s": round(_pct(outside, 0.99), 4),
        "page_ms_p50": round(_pct(pages.ms, 0.50), 1),
        "page_ms_p99": round(_pct(pages.ms, 0.99), 1), "page_fetches": len(pages.ms),
        "broker_restart_down_s": down, "drain_after_end_s": round(drain_s, 1),
        "machine": platform.platform(), "cpus": os.cpu_count(),
    }
    service.stop()
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
