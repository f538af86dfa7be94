"""`host fleet serve|status|web|export`: the fleet's database, fed from the MQTT broker."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time

NAME = "fleet"
HELP = ("the fleet of boxes: store what they publish (serve), list every machine (status), "
        "the read-only web page (web), a machine's service log as a run CSV (export)")


def _db(p: argparse.ArgumentParser) -> None:
    p.add_argument("--db", metavar="URL", default=None,
                   help="sqlite:///path (or a path) or postgresql://user@host:port/db "
                   "(default: $THERMALCOMP_FLEET_DB or ~/.local/share/thermalcomp/fleet.sqlite)")


def register(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="fleet_command", required=True, metavar="ACTION")
    serve = sub.add_parser("serve", help="subscribe to thermalcomp/# and store every machine's "
                           "messages (persistent session, QoS 1)")
    serve.add_argument("--mqtt", required=True, metavar="URL",
                       help="broker: mqtt://[user[:password]@]host[:port] or mqtts://...")
    _db(serve)
    serve.add_argument("--machine", action="append", default=[], metavar="NAME[=HASH]",
                       help="a machine of the fleet, optionally with the model hash it must "
                       "run (repeat); when given, messages from any other machine are "
                       "refused as unknown")
    serve.add_argument("--client-id", help="MQTT client id of the persistent session "
                       "(default tc-fleet-<hostname>)")
    serve.add_argument("--http", type=int, metavar="PORT",
                       help="also serve the read-only page on this port")
    serve.add_argument("--bind", default="127.0.0.1", help="page address (default 127.0.0.1)")
    serve.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    status = sub.add_parser("status", help="print every machine: online/offline/stale, "
                            "faults, EXTRAP/CLAMP, last probe residual, model hash")
    _db(status)
    status.add_argument("--json", action="store_true", help="one JSON array")
    web = sub.add_parser("web", help="serve the read-only fleet page")
    _db(web)
    web.add_argument("--port", type=int, default=8045, help="default 8045")
    web.add_argument("--bind", default="127.0.0.1", help="default 127.0.0.1")
    export = sub.add_parser("export", help="a machine's service log in the run format "
                            "(host train / host evaluate)")
    export.add_argument("machine")
    _db(export)
    export.add_argument("--since", default="24h", help="ISO date/time, 24h/90min/2d ago, or "
                        "unix seconds (default 24h)")
    export.add_argument("--until", help="same forms (default: now)")
    export.add_argument("-o", "--output", required=True, metavar="CSV")


def _machines(specs: list[str]) -> dict[str, str | None]:
    from thermal_comp.host.fleet.topics import check_machine

    out: dict[str, str | None] = {}
    for spec in specs:
        name, _, expected = spec.partition("=")
        out[check_machine(name)] = expected or None
    return out


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    from thermal_comp.host.fleet.store import Store

    if args.fleet_command == "serve":
        from thermal_comp.host.fleet.collector import Collector

        store = Store(args.db)
        collector = Collector(args.mqtt, store, _machines(args.machine), args.client_id)
        if args.http:
            from thermal_comp.host.fleet.web import make_server

            server = make_server(store.url, args.http, args.bind)
            threading.Thread(target=server.serve_forever, daemon=True).start()
            print(f"fleet page on http://{args.bind}:{args.http}/", file=sys.stderr)
        collector.run(args.duration)
        print(f"fleet: {collector.stored} stored, {collector.refused} refused", file=sys.stderr)
        return 0
    if args.fleet_command == "web":
        from thermal_comp.host.fleet.web import make_server

        store = Store(args.db)  # creates the tables, checks the URL
        server = make_server(store.url, args.port, args.bind)
        print(f"fleet page on http://{args.bind}:{args.port}/ (Ctrl-C stops)", file=sys.stderr)
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass
        return 0
    if args.fleet_command == "status":
        from thermal_comp.host.fleet.web import machine_summary

        now = time.time()
        rows = [machine_summary(m, now) for m in Store(args.db).machines()]
        if args.json:
            print(json.dumps(rows, indent=1))
            return 0
        print(_status_table(rows, now))
        return 0
    from thermal_comp.host.fleet.export import export_run, parse_since

    now = time.time()
    until = parse_since(args.until, now) if args.until else None
    done = export_run(Store(args.db), args.machine, parse_since(args.since, now), args.output,
                      until)
    print(f"{done.path}: {done.rows} rows ({done.missing_rows} missing, left for "
          f"--fill-gaps), {done.probes} probe readings, model {done.model_hash}"
          + (f"; {done.left_out} earlier samples left out (another power-up, model or "
             "layout)" if done.left_out else ""))
    return 0


def _status_table(rows: list[dict], now: float) -> str:
    if not rows:
        return "no machine has reported yet"
    head = ["machine", "status", "age_s", "seq", "flags", "faults", "EXTRAP/CLAMP",
            "probe residual um", "model hash"]
    table = [head]
    for r in rows:
        age = "-" if r["last_seen"] is None else f"{now - r['last_seen']:.0f}"
        res = r["last_probe_residual_um"]
        hash_text = r["model_hash"] or "?"
        if r["flag"]:
            hash_text += f"  FLAG: {r['flag']}"
        table.append([r["machine"], r["status"], age, str(r["seq"] if r["seq"] is not None
                                                             else "-"),
                      ",".join(r["flags"]) or "ok",
                      ";".join(f"{c}:{'/'.join(f)}" for c, f in r["faults"].items()) or "-",
                      f"{'EXTRAP ' if r['extrap_now'] else ''}{'CLAMP ' if r['clamp_now'] else ''}"
                      f"{r['extrap_samples']}/{r['clamp_samples']}",
                      ",".join(f"{a}={v:+.2f}" for a, v in res.items()) if res else "-",
                      hash_text])
    widths = [max(len(row[i]) for row in table[:]) for i in range(len(head) - 1)]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(row[:-1], widths, strict=True))
                     + "  " + row[-1] for row in table)
