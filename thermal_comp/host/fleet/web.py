"""The fleet page: every machine's state and its day as a plot, read-only (stdlib
http.server, inline SVG, no script).

``/``: one row per machine (online/offline/stale, the flags of its last sample, faulted
channels, EXTRAP/CLAMP sample counts, the last probe residual, the model hash and any flag on
it) with its correction per axis over the last 24 h (the last state of each minute) and the
drift its probes measured (correction + residual) as dots; then the refused messages and the
latest events, each with its reason. ``/machine/<name>``: one machine, larger, with its
events. ``/status.json``: the table as JSON. Anything but GET/HEAD is refused (405).
"""

from __future__ import annotations

import html
import json
import logging
import threading
import time
from collections.abc import Sequence
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import unquote

from thermal_comp.host.fleet.store import MachineRow, Store

log = logging.getLogger("thermal_comp.host.fleet.web")
DAY_S = 86400.0
COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b")
_STATUS_COLOUR = {"online": "#2ca02c", "offline": "#7f7f7f", "stale": "#d62728",
                  "unseen": "#7f7f7f"}


def _fmt_t(t: float | None, now: float) -> str:
    if t is None:
        return "never"
    age = now - t
    stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t))
    return f"{stamp} ({age:.0f} s ago)" if age < 3600 else stamp


def svg_plot(trend: Sequence[tuple[float, dict, dict | None]], t0: float, t1: float,
             width: int = 360, height: int = 90) -> str:
    """Correction per axis (lines) and probe-measured drift (dots) against time, in µm."""
    series: dict[str, list[tuple[float, float]]] = {}
    dots: dict[str, list[tuple[float, float]]] = {}
    for t, corr, probe in trend:
        for axis, v in corr.items():
            if v is not None:
                series.setdefault(axis, []).append((t, float(v)))
        if probe and probe.get("residual_um"):
            for axis, r in probe["residual_um"].items():
                if axis in corr and corr[axis] is not None and r is not None:
                    dots.setdefault(axis, []).append((t, float(corr[axis]) + float(r)))
    values = [v for s in (*series.values(), *dots.values()) for _, v in s]
    if not values:
        return (f'<svg width="{width}" height="{height}" role="img"><text x="8" y="{height // 2}"'
                ' font-size="11" fill="#777">no data today</text></svg>')
    lo, hi = min(values + [0.0]), max(values + [0.0])
    if hi - lo < 1e-6:
        lo, hi = lo - 1, hi + 1
    pad_l, pad_r, pad_y = 40, 6, 8

    def x(t: float) -> float:
        return pad_l + (t - t0) / max(t1 - t0, 1e-9) * (width - pad_l - pad_r)

    def y(v: float) -> float:
        return pad_y + (hi - v) / (hi - lo) * (height - 2 * pad_y)

    parts = [f'<svg width="{width}" height="{height}" role="img" '
             f'xmlns="http://www.w3.org/2000/svg"><rect width="100%" height="100%" '
             f'fill="#fafafa"/>',
             f'<line x1="{pad_l}" x2="{width - pad_r}" y1="{y(0):.1f}" y2="{y(0):.1f}" '
             f'stroke="#ccc"/>',
             f'<text x="2" y="{pad_y + 8}" font-size="10">{hi:+.1f}</text>',
             f'<text x="2" y="{height - 2}" font-size="10">{lo:+.1f}</text>']
    for i, (axis, pts) in enumerate(sorted(series.items())):
        colour = COLOURS[i % len(COLOURS)]
        path = " ".join(f"{x(t):.1f},{y(v):.1f}" for t, v in pts)
        parts.append(f'<polyline fill="none" stroke="{colour}" stroke-width="1.3" '
                     f'points="{path}"><title>{html.escape(axis)} correction</title></polyline>')
        for t, v in dots.get(axis, []):
            parts.append(f'<circle cx="{x(t):.1f}" cy="{y(v):.1f}" r="2.5" fill="{colour}">'
                         f'<title>{html.escape(axis)} probe: {v:+.2f}</title></circle>')
    legend = " ".join(f'<tspan fill="{COLOURS[i % len(COLOURS)]}">{html.escape(a)}</tspan>'
                      for i, a in enumerate(sorted(series)))
    parts.append(f'<text x="{pad_l + 4}" y="{height - 2}" font-size="10">{legend} µm, '
                 'dots: probed drift</text></svg>')
    return "".join(parts)


def machine_summary(m: MachineRow, now: float) -> dict[str, Any]:
    """One machine as the page and `host fleet status` show it."""
    state = m.state or {}
    flags = state.get("flags", [])
    probe = m.last_probe or {}
    return {
        "machine": m.name, "status": m.status(now), "last_seen": m.last_t,
        "seq": state.get("seq"), "flags": flags,
        "faults": state.get("faults") or {},
        "extrap_now": "EXTRAP" in flags, "clamp_now": "CLAMP" in flags,
        "extrap_samples": m.extrap_n, "clamp_samples": m.clamp_n, "samples": m.samples_n,
        "corrections_um": state.get("corrections_um") or {},
        "last_probe_residual_um": probe.get("residual_um"), "last_probe_t": probe.get("t"),
        "model_hash": m.model_hash, "expected_hash": m.expected_hash, "flag": m.flag,
        "known": m.known,
    }


_CSS = """body{font-family:sans-serif;margin:1em;color:#222}table{border-collapse:collapse}
td,th{border-bottom:1px solid #ddd;padding:4px 8px;text-align:left;vertical-align:top;
font-size:13px}.flag{color:#b00;font-weight:bold}.dim{color:#777}.st{font-weight:bold}"""


def _row(m: MachineRow, trend: list, now: float, link: bool = True) -> str:
    s = machine_summary(m, now)
    e = html.escape
    name = (f'<a href="/machine/{e(m.name)}">{e(m.name)}</a>' if link else e(m.name))
    faults = "<br>".join(f"{e(c)}: {e('/'.join(f))}" for c, f in s["faults"].items()) or "—"
    flags = ", ".join(e(f) for f in s["flags"]) or "ok"
    residual = s["last_probe_residual_um"]
    res_text = (", ".join(f"{e(a)} {v:+.2f} µm" for a, v in residual.items()) if residual
                else "—")
    corr = ", ".join(f"{e(a)} {v:+.2f}" for a, v in s["corrections_um"].items()
                     if v is not None) or "—"
    hash_cell = e(m.model_hash or "?")
    if m.flag:
        hash_cell += f'<br><span class="flag">{e(m.flag)}</span>'
    status = s["status"]
    return (f"<tr><td>{name}</td><td class='st' style='color:{_STATUS_COLOUR[status]}'>"
            f"{status}<br><span class='dim'>{e(_fmt_t(m.last_t, now))}</span></td>"
            f"<td>#{s['seq'] if s['seq'] is not None else '—'}<br>{flags}</td><td>{corr}</td>"
            f"<td>{faults}</td><td>{m.extrap_n} / {m.clamp_n}</td><td>{res_text}</td>"
            f"<td>{hash_cell}</td><td>{svg_plot(trend, now - DAY_S, now)}</td></tr>")


_HEAD = ("<tr><th>machine</th><th>status</th><th>sample, flags</th><th>correction µm</th>"
         "<th>faults</th><th>EXTRAP / CLAMP samples</th><th>last probe residual</th>"
         "<th>model hash</th><th>correction and probed drift, last 24 h</th></tr>")


def _page(title: str, body: str) -> str:
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
            f"</title><meta http-equiv='refresh' content='10'><style>{_CSS}</style></head>"
            f"<body>{body}</body></html>")


def render_fleet(store: Store, now: float | None = None) -> str:
    now = time.time() if now is None else now
    machines = store.machines()
    trend = store.trend(now - DAY_S)
    counts: dict[str, int] = {}
    for m in machines:
        st = m.status(now)
        counts[st] = counts.get(st, 0) + 1
    summary = ", ".join(f"{n} {k}" for k, n in sorted(counts.items())) or "no machine yet"
    rows = "".join(_row(m, trend.get(m.name, []), now) for m in machines)
    e = html.escape
    refused = "".join(
        f"<tr><td>{e(_fmt_t(t, now))}</td><td>{e(machine or '?')}</td><td>{e(topic)}</td>"
        f"<td class='flag'>{e(reason)}</td><td class='dim'>{e(excerpt[:80])}</td></tr>"
        for t, topic, machine, reason, excerpt in store.refusals(20))
    events = "".join(
        f"<tr><td>{e(_fmt_t(t, now))}</td><td>{e(m)}</td><td>{e(k)}</td><td>{e(msg)}</td></tr>"
        for t, m, k, msg in store.events(limit=20, kinds=("model_changed", "bad_line",
                                                           "unknown_line", "command", "probe",
                                                           "lost")))
    body = (f"<h1>Thermal compensation fleet</h1><p>{len(machines)} machines: {summary}. "
            f"Read-only; refreshed every 10 s.</p><table>{_HEAD}{rows}</table>"
            f"<h2>Refused messages</h2><table><tr><th>when</th><th>machine</th><th>topic</th>"
            f"<th>reason</th><th>message</th></tr>{refused or '<tr><td>none</td></tr>'}</table>"
            f"<h2>Events</h2><table><tr><th>when</th><th>machine</th><th>kind</th>"
            f"<th>what</th></tr>{events or '<tr><td>none</td></tr>'}</table>")
    return _page("fleet", body)


def render_machine(store: Store, name: str, now: float | None = None) -> str | None:
    now = time.time() if now is None else now
    m = next((m for m in store.machines() if m.name == name), None)
    if m is None:
        return None
    trend = store.trend(now - DAY_S, machine=name).get(name, [])
    e = html.escape
    events = "".join(f"<tr><td>{e(_fmt_t(t, now))}</td><td>{e(k)}</td><td>{e(msg)}</td></tr>"
                     for t, _, k, msg in store.events(machine=name, limit=50))
    body = (f"<p><a href='/'>fleet</a></p><h1>{e(name)}</h1><table>{_HEAD}"
            f"{_row(m, trend, now, link=False)}</table>"
            f"<p>{svg_plot(trend, now - DAY_S, now, width=900, height=260)}</p>"
            f"<h2>Events</h2><table>{events or '<tr><td>none</td></tr>'}</table>")
    return _page(name, body)


class _Handler(BaseHTTPRequestHandler):
    server_version = "thermalcomp-fleet"
    db_url: str = ""
    _local = threading.local()

    def _store(self) -> Store:
        store = getattr(self._local, "store", None)
        if store is None:
            store = Store(self.db_url)
            self._local.store = store
        return store

    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        path = self.path.split("?", 1)[0]
        try:
            store = self._store()
            if path == "/":
                self._send(200, render_fleet(store))
            elif path.startswith("/machine/"):
                page = render_machine(store, unquote(path.removeprefix("/machine/")))
                self._send(404 if page is None else 200, page or _page("?", "no such machine"))
            elif path == "/status.json":
                now = time.time()
                self._send(200, json.dumps([machine_summary(m, now) for m in store.machines()]),
                           "application/json")
            else:
                self._send(404, _page("not found", "not found"))
        except Exception as exc:  # noqa: BLE001 - a page error must not stop the server
            log.exception("page %s failed", path)
            self._send(500, _page("error", f"error: {html.escape(str(exc))}"))

    def do_HEAD(self) -> None:  # noqa: N802
        self.do_GET()

    def _refuse(self) -> None:
        self._send(405, _page("read-only", "this page is read-only"))

    do_POST = do_PUT = do_DELETE = do_PATCH = _refuse  # noqa: N815

    def _send(self, code: int, text: str, ctype: str = "text/html; charset=utf-8") -> None:
        data = text.encode()
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(data)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002
        log.debug("%s " + format, self.address_string(), *args)


def make_server(db_url: str, port: int = 8045, host: str = "127.0.0.1") -> ThreadingHTTPServer:
    """The page's server (not started: ``serve_forever()`` or a thread)."""
    handler = type("Handler", (_Handler,), {"db_url": db_url, "_local": threading.local()})
    server = ThreadingHTTPServer((host, port), handler)
    server.daemon_threads = True
    return server
