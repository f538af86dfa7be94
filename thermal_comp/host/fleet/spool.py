"""The gateway's on-disk spool: every message is on disk until the broker has acknowledged it.

paho-mqtt keeps QoS 1 messages in memory until their PUBACK; a gateway killed during a broker
outage (a reboot, a systemd restart, a crash) would lose them. So each message is appended to
the spool (JSON lines) before it is handed to paho, and an ``{"ack": key}`` line follows when
its PUBACK arrives. A gateway starting on the same spool re-publishes, in order, the messages
that have no ack line. A message acknowledged but whose ack line was not written before the
kill is sent twice; the store keeps each (machine, gateway, n) once, so it is stored once.

The file stays small: when nothing is outstanding it is truncated (a healthy broker
acknowledges within milliseconds, so between samples), and after a long outage it is
rewritten without the acknowledged messages once they outnumber the rest. A message line is
flushed and fsynced before the message is published (a kill loses nothing, a power cut
neither); ack lines are only flushed (losing one costs a duplicate, not a message). One
gateway per spool: a second one on the same file is refused (``flock`` on ``<spool>.lock``).

Default path: ``$XDG_STATE_HOME/thermalcomp/spool-<machine>.jsonl`` (``~/.local/state/...``).
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import threading
from pathlib import Path
from typing import Any, TextIO

from thermal_comp.host.fleet.topics import FleetError

log = logging.getLogger("thermal_comp.host.fleet.spool")

# rewrite the file once this many ack lines have piled up and outnumber the open messages
COMPACT_ACKS = 10_000


def default_spool_path(machine: str) -> Path:
    state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(state) / "thermalcomp" / f"spool-{machine}.jsonl"


def message_key(data: dict[str, Any]) -> str:
    """A message's identity across gateway runs: the store's (gateway, n)."""
    return f"{data.get('gateway')}:{data.get('n')}"


class Spool:
    """Messages not yet acknowledged, on disk. ``recovered``: those an earlier run left
    (kind, data), oldest first; they are already in the file and stay there until acked."""

    def __init__(self, path: str | Path, fsync: bool = True) -> None:
        self.path = Path(path).expanduser()
        self.fsync = fsync
        self._lock = threading.Lock()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._lockfile = open(f"{self.path}.lock", "a")  # noqa: SIM115 (held until close)
        except OSError as exc:
            raise FleetError(f"spool {self.path}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(self._lockfile, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._lockfile.close()
            raise FleetError(f"spool {self.path} is in use by another gateway (or monitor "
                             "--mqtt) for this machine: one per box, or give --spool") from None
        self._open: dict[str, tuple[str, dict[str, Any]]] = self._read()
        self.recovered = list(self._open.values())
        self._acks = 0
        self._fh: TextIO = self._rewrite()
        if self.recovered:
            log.warning("spool %s: %d message(s) of an earlier run not acknowledged by the "
                        "broker: publishing them again first", self.path, len(self.recovered))

    def _read(self) -> dict[str, tuple[str, dict[str, Any]]]:
        out: dict[str, tuple[str, dict[str, Any]]] = {}
        if not self.path.exists():
            return out
        bad = 0
        with self.path.open(encoding="utf-8", errors="replace") as fh:
            for line in fh:
                try:
                    rec = json.loads(line)
                    if "ack" in rec:
                        out.pop(str(rec["ack"]), None)
                    else:
                        out[str(rec["key"])] = (str(rec["kind"]), dict(rec["data"]))
                except (ValueError, KeyError, TypeError):
                    bad += 1  # a line cut short by the kill: its message was never published
        if bad:
            log.warning("spool %s: %d unreadable line(s) skipped", self.path, bad)
        return out

    def _rewrite(self) -> TextIO:
        """The file with only the open messages (atomically), opened for appending."""
        tmp = self.path.with_name(self.path.name + ".tmp")
        with tmp.open("w", encoding="utf-8") as fh:
            for key, (kind, data) in self._open.items():
                fh.write(_line({"key": key, "kind": kind, "data": data}))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, self.path)
        self._acks = 0
        return self.path.open("a", encoding="utf-8")

    def add(self, key: str, kind: str, data: dict[str, Any]) -> None:
        """On disk before it is published."""
        with self._lock:
            self._open[key] = (kind, data)
            self._fh.write(_line({"key": key, "kind": kind, "data": data}))
            self._fh.flush()
            if self.fsync:
                os.fsync(self._fh.fileno())

    def ack(self, key: str) -> None:
        with self._lock:
            if self._open.pop(key, None) is None or self._fh.closed:
                return
            if not self._open:  # nothing outstanding: start afresh
                self._fh.truncate(0)
                self._acks = 0
                return
            self._fh.write(_line({"ack": key}))
            self._fh.flush()
            self._acks += 1
            if self._acks >= COMPACT_ACKS and self._acks > 2 * len(self._open):
                self._fh.close()
                self._fh = self._rewrite()

    def pending(self) -> int:
        with self._lock:
            return len(self._open)

    def close(self) -> None:
        with self._lock:
            if not self._fh.closed:
                self._fh.close()
        self._lockfile.close()  # releases the flock


def _line(rec: dict[str, Any]) -> str:
    return json.dumps(rec, separators=(",", ":"), ensure_ascii=False) + "\n"
