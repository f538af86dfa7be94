"""The fleet's database: SQLite at a default path (embedded, no server), PostgreSQL by URL.

One schema, the same SQL on both (``?`` placeholders become ``%s`` for psycopg):

- ``machines``: one row per machine: online/offline, its last state (JSON), model hash, the
  hash it should run (``--machine NAME=HASH``), the latest flag (a changed or unexpected
  model hash), the last probe residual, EXTRAP/CLAMP sample counts.
- ``samples``: every state, keyed (machine, gateway, n): a message delivered twice is stored
  once, a missing n is a lost one.
- ``trend``: the last state of each machine per minute (the page's plot of the day).
- ``events``: INFO, model changes, bad/unknown lines, probe answers, commands.
- ``refused``: messages not stored, with the reason.

``open_store("sqlite:///path")``, a plain path, or ``"postgresql://user@host:port/db"``;
None: ``$THERMALCOMP_FLEET_DB`` or ``~/.local/share/thermalcomp/fleet.sqlite``.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from thermal_comp.host.fleet.topics import FleetError, Message

DB_ENV = "THERMALCOMP_FLEET_DB"
TREND_BUCKET_S = 60
STALE_MIN_S = 5.0
STALE_PERIODS = 3.0

_TABLES = """
CREATE TABLE IF NOT EXISTS machines (
    name TEXT PRIMARY KEY, known INTEGER NOT NULL DEFAULT 0, first_seen DOUBLE PRECISION,
    online INTEGER, online_t DOUBLE PRECISION, last_t DOUBLE PRECISION, last_state TEXT,
    model_hash TEXT, expected_hash TEXT, flag TEXT, flag_t DOUBLE PRECISION,
    period_ms INTEGER, last_probe TEXT, extrap_n BIGINT NOT NULL DEFAULT 0,
    clamp_n BIGINT NOT NULL DEFAULT 0, samples_n BIGINT NOT NULL DEFAULT 0);
CREATE TABLE IF NOT EXISTS samples (
    machine TEXT NOT NULL, gateway TEXT NOT NULL, n BIGINT NOT NULL, t DOUBLE PRECISION NOT NULL,
    seq BIGINT NOT NULL, status TEXT NOT NULL, flags TEXT NOT NULL, model_hash TEXT,
    period_ms INTEGER, corrections TEXT NOT NULL, temperatures TEXT NOT NULL, faults TEXT,
    probe TEXT, stored_t DOUBLE PRECISION NOT NULL, PRIMARY KEY (machine, gateway, n));
CREATE INDEX IF NOT EXISTS samples_machine_t ON samples (machine, t);
CREATE TABLE IF NOT EXISTS trend (
    machine TEXT NOT NULL, bucket BIGINT NOT NULL, t DOUBLE PRECISION NOT NULL,
    corrections TEXT NOT NULL, probe TEXT, PRIMARY KEY (machine, bucket));
CREATE TABLE IF NOT EXISTS events (
    machine TEXT NOT NULL, gateway TEXT NOT NULL, n BIGINT NOT NULL, t DOUBLE PRECISION NOT NULL,
    kind TEXT NOT NULL, message TEXT NOT NULL, data TEXT, PRIMARY KEY (machine, gateway, n));
CREATE INDEX IF NOT EXISTS events_t ON events (t);
"""
_REFUSED = {
    "sqlite": "CREATE TABLE IF NOT EXISTS refused (id INTEGER PRIMARY KEY AUTOINCREMENT, "
              "t DOUBLE PRECISION NOT NULL, topic TEXT, machine TEXT, reason TEXT NOT NULL, "
              "excerpt TEXT)",
    "postgresql": "CREATE TABLE IF NOT EXISTS refused (id BIGSERIAL PRIMARY KEY, "
                  "t DOUBLE PRECISION NOT NULL, topic TEXT, machine TEXT, reason TEXT NOT NULL, "
                  "excerpt TEXT)",
}


def default_db() -> str:
    env = os.environ.get(DB_ENV)
    if env:
        return env
    base = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
    return f"sqlite:///{base / 'thermalcomp' / 'fleet.sqlite'}"


@dataclass(frozen=True)
class MachineRow:
    name: str
    known: bool
    online: bool | None
    last_t: float | None
    state: dict[str, Any] | None
    model_hash: str | None
    expected_hash: str | None
    flag: str | None
    last_probe: dict[str, Any] | None
    extrap_n: int
    clamp_n: int
    samples_n: int
    period_ms: int | None

    def status(self, now: float) -> str:
        """online / offline / stale (online, but no state for STALE_PERIODS periods, at least
        STALE_MIN_S) / unseen."""
        if self.online is False:
            return "offline"
        if self.last_t is None:
            return "unseen" if self.online is None else "online"
        limit = max(STALE_MIN_S, STALE_PERIODS * (self.period_ms or 1000) / 1000.0)
        if now - self.last_t > limit:
            return "stale"
        return "online"


def _json(obj: Any) -> str | None:
    return None if obj is None else json.dumps(obj, separators=(",", ":"))


class Store:
    """One connection to the fleet's database; use one Store per thread."""

    def __init__(self, url: str | None = None) -> None:
        url = url or default_db()
        self.url = url
        if url.startswith(("postgresql://", "postgres://")):
            import psycopg  # the [fleet] extra

            self.dialect = "postgresql"
            try:
                self.conn = psycopg.connect(url, autocommit=False)
            except psycopg.Error as exc:
                raise FleetError(f"database {_safe(url)}: {str(exc).strip()[:300]}") from None
            self._errors: tuple[type[BaseException], ...] = (psycopg.Error,)
        else:
            path = url.removeprefix("sqlite:///") if url.startswith("sqlite:") else url
            if url.startswith("sqlite:") and not url.startswith("sqlite:///"):
                raise FleetError(f"database URL {url!r}: use sqlite:///path or a path")
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            self.dialect = "sqlite"
            self.conn = sqlite3.connect(path, timeout=30, check_same_thread=False)
            self.conn.execute("PRAGMA journal_mode=WAL")
            self.conn.execute("PRAGMA synchronous=NORMAL")
            self._errors = (sqlite3.Error,)
        self._hash: dict[str, str | None] = {}
        self._create()

    # ---- plumbing ------------------------------------------------------------------------
    def _sql(self, sql: str) -> str:
        return sql.replace("?", "%s") if self.dialect == "postgresql" else sql

    def _exec(self, sql: str, params: Sequence[Any] = ()) -> Any:
        cur = self.conn.cursor()
        cur.execute(self._sql(sql), tuple(params))
        return cur

    def _rows(self, sql: str, params: Sequence[Any] = ()) -> list[tuple]:
        rows = self._exec(sql, params).fetchall()
        self.conn.commit()  # end the read transaction (psycopg would hold it open)
        return rows

    def _create(self) -> None:
        for stmt in [*_TABLES.split(";"), _REFUSED[self.dialect]]:
            if stmt.strip():
                self._exec(stmt)
        self.conn.commit()

    def close(self) -> None:
        self.conn.close()

    # ---- writing ---------------------------------------------------------------------------
    def register(self, machine: str, expected_hash: str | None = None) -> None:
        """A machine the fleet expects (``serve --machine NAME[=HASH]``)."""
        self._exec("INSERT INTO machines (name, known, first_seen) VALUES (?, 1, ?) "
                   "ON CONFLICT (name) DO NOTHING", (machine, time.time()))
        self._exec("UPDATE machines SET known = 1, expected_hash = ? WHERE name = ?",
                   (expected_hash, machine))
        self.conn.commit()

    def known(self, machine: str) -> bool:
        rows = self._rows("SELECT known FROM machines WHERE name = ?", (machine,))
        return bool(rows and rows[0][0])

    def _ensure(self, machine: str, t: float) -> None:
        self._exec("INSERT INTO machines (name, known, first_seen) VALUES (?, 0, ?) "
                   "ON CONFLICT (name) DO NOTHING", (machine, t))

    def add(self, msg: Message, now: float | None = None) -> list[str]:
        """Store one accepted message; returns the flags it raised (for the log). Commits."""
        now = time.time() if now is None else now
        try:
            if msg.kind == "online":
                self._ensure(msg.machine, now)
                self._exec("UPDATE machines SET online = ?, online_t = ? WHERE name = ?",
                           (int(msg.data["online"]), now, msg.machine))
                notes: list[str] = []
            elif msg.kind == "state":
                notes = self._add_state(msg, now)
            else:
                notes = self._add_event(msg)
            self.conn.commit()
        except self._errors:
            self.conn.rollback()
            raise
        return notes

    def _add_state(self, msg: Message, now: float) -> list[str]:
        d, m = msg.data, msg.machine
        self._ensure(m, d["t"])
        cur = self._exec(
            "INSERT INTO samples (machine, gateway, n, t, seq, status, flags, model_hash, "
            "period_ms, corrections, temperatures, faults, probe, stored_t) VALUES "
            "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT DO NOTHING",
            (m, d["gateway"], d["n"], d["t"], d["seq"], d["status"], _json(d["flags"]),
             d.get("model_hash"), d.get("period_ms"), _json(d["corrections_um"]),
             _json(d["temperatures_c"]), _json(d["faults"]), _json(d.get("probe")), now))
        if cur.rowcount == 0:
            return []  # delivered twice (a resend, a retained copy): stored once
        flags = d["flags"]
        self._exec(
            "INSERT INTO trend (machine, bucket, t, corrections, probe) VALUES (?, ?, ?, ?, ?) "
            "ON CONFLICT (machine, bucket) DO UPDATE SET t = excluded.t, "
            "corrections = excluded.corrections, probe = excluded.probe",
            (m, int(d["t"] // TREND_BUCKET_S), d["t"], _json(d["corrections_um"]),
             _json(d.get("probe"))))
        self._exec(
            "UPDATE machines SET samples_n = samples_n + 1, extrap_n = extrap_n + ?, "
            "clamp_n = clamp_n + ? WHERE name = ?",
            (int("EXTRAP" in flags), int("CLAMP" in flags), m))
        self._exec(
            "UPDATE machines SET last_t = ?, last_state = ?, period_ms = ?, "
            "last_probe = COALESCE(?, last_probe) WHERE name = ? AND "
            "(last_t IS NULL OR last_t <= ?)",
            (d["t"], _json(d), d.get("period_ms"), _json(d.get("probe")), m, d["t"]))
        return self._check_hash(m, d.get("model_hash"), d["t"])

    def _check_hash(self, machine: str, model_hash: str | None, t: float) -> list[str]:
        if model_hash is None:
            return []
        if machine not in self._hash:
            rows = self._exec("SELECT model_hash FROM machines WHERE name = ?",
                              (machine,)).fetchall()
            self._hash[machine] = rows[0][0] if rows else None
        before = self._hash[machine]
        if before == model_hash:
            return []
        self._hash[machine] = model_hash
        rows = self._exec("SELECT expected_hash FROM machines WHERE name = ?",
                          (machine,)).fetchall()
        expected = rows[0][0] if rows else None
        notes = []
        if before is not None:
            notes.append(f"model hash changed from {before} to {model_hash}: a new model on "
                         "the box (reflashed or swapped); check it was meant")
        if expected is not None and model_hash != expected:
            notes.append(f"runs model {model_hash}, the fleet expects {expected}")
        self._exec("UPDATE machines SET model_hash = ? WHERE name = ?", (model_hash, machine))
        if notes:
            self._exec("UPDATE machines SET flag = ?, flag_t = ? WHERE name = ?",
                       ("; ".join(notes), t, machine))
        return notes

    def _add_event(self, msg: Message) -> list[str]:
        d = msg.data
        self._ensure(msg.machine, d["t"])
        extra = {k: v for k, v in d.items()
                 if k not in ("schema", "machine", "gateway", "n", "t", "event", "message")}
        self._exec("INSERT INTO events (machine, gateway, n, t, kind, message, data) VALUES "
                   "(?, ?, ?, ?, ?, ?, ?) ON CONFLICT DO NOTHING",
                   (msg.machine, d["gateway"], d["n"], d["t"], d["event"], d["message"],
                    _json(extra)))
        return []

    def refuse(self, topic: str, machine: str | None, reason: str, payload: bytes,
               now: float | None = None) -> None:
        excerpt = payload[:120].decode("utf-8", errors="backslashreplace")
        self._exec("INSERT INTO refused (t, topic, machine, reason, excerpt) VALUES "
                   "(?, ?, ?, ?, ?)", (time.time() if now is None else now, topic[:200],
                                       machine, reason[:500], excerpt))
        self.conn.commit()

    # ---- reading ---------------------------------------------------------------------------
    def machines(self) -> list[MachineRow]:
        rows = self._rows(
            "SELECT name, known, online, last_t, last_state, model_hash, expected_hash, flag, "
            "last_probe, extrap_n, clamp_n, samples_n, period_ms FROM machines ORDER BY name")
        return [MachineRow(r[0], bool(r[1]), None if r[2] is None else bool(r[2]), r[3],
                           json.loads(r[4]) if r[4] else None, r[5], r[6], r[7],
                           json.loads(r[8]) if r[8] else None, int(r[9]), int(r[10]),
                           int(r[11]), r[12]) for r in rows]

    def trend(self, since: float, machine: str | None = None
              ) -> dict[str, list[tuple[float, dict, dict | None]]]:
        sql = "SELECT machine, t, corrections, probe FROM trend WHERE bucket >= ?"
        params: list[Any] = [int(since // TREND_BUCKET_S)]
        if machine is not None:
            sql += " AND machine = ?"
            params.append(machine)
        out: dict[str, list[tuple[float, dict, dict | None]]] = {}
        for m, t, corr, probe in self._rows(sql + " ORDER BY machine, bucket", params):
            out.setdefault(m, []).append((t, json.loads(corr),
                                          json.loads(probe) if probe else None))
        return out

    def samples(self, machine: str, since: float = 0.0, until: float | None = None
                ) -> list[dict[str, Any]]:
        sql = ("SELECT t, seq, status, flags, model_hash, period_ms, corrections, temperatures, "
               "probe, gateway, n FROM samples WHERE machine = ? AND t >= ?")
        params: list[Any] = [machine, since]
        if until is not None:
            sql += " AND t <= ?"
            params.append(until)
        keys = ("t", "seq", "status", "flags", "model_hash", "period_ms", "corrections_um",
                "temperatures_c", "probe", "gateway", "n")
        out = []
        for r in self._rows(sql + " ORDER BY t, gateway, n", params):
            row = dict(zip(keys, r, strict=True))
            for k in ("flags", "corrections_um", "temperatures_c", "probe"):
                row[k] = json.loads(row[k]) if row[k] else None
            out.append(row)
        return out

    def events(self, machine: str | None = None, limit: int = 50,
               kinds: Iterable[str] | None = None) -> list[tuple[float, str, str, str]]:
        sql, params = "SELECT t, machine, kind, message FROM events WHERE 1 = 1", []
        if machine is not None:
            sql += " AND machine = ?"
            params.append(machine)
        if kinds is not None:
            kinds = list(kinds)
            sql += f" AND kind IN ({', '.join('?' for _ in kinds)})"
            params += kinds
        return [tuple(r) for r in self._rows(sql + f" ORDER BY t DESC LIMIT {int(limit)}",
                                             params)]

    def refusals(self, limit: int = 50) -> list[tuple[float, str, str | None, str, str]]:
        return [tuple(r) for r in self._rows(
            f"SELECT t, topic, machine, reason, excerpt FROM refused ORDER BY id DESC "
            f"LIMIT {int(limit)}")]

    def counts(self) -> dict[str, int]:
        """machine -> stored samples (the bench compares them with what was sent)."""
        return {m: int(c) for m, c in self._rows(
            "SELECT machine, COUNT(*) FROM samples GROUP BY machine")}

    def latencies(self) -> list[tuple[float, float]]:
        """(t, stored_t - t) of every sample, seconds: broker + service + commit."""
        return [(float(t), float(d)) for t, d in self._rows("SELECT t, stored_t - t FROM samples")]


def _safe(url: str) -> str:
    """A database URL without its password, for messages."""
    from urllib.parse import urlsplit

    p = urlsplit(url)
    if p.password:
        return url.replace(f":{p.password}@", ":***@")
    return url


def open_store(url: str | None = None) -> Store:
    return Store(url)
