"""The monitor's fault history: what faulted, when, and when it cleared.

A fault flag on the box (HOLD, OPEN, RANGE, EXTRAP, ...) comes and goes with the samples; the
live line only ever shows the present. A metrologist who looks at the screen after lunch wants
to know that T12 was open for 40 s at 12:03 and that dz held meanwhile. So every flag that is
not routine (SLEW, REFERENCED) opens an entry when it comes up and closes it when a sample
without it arrives; the link's own troubles (STALE, DISCONNECTED) are entries too, opened and
closed by the reader.

Entries are keyed by what is faulted: a sample flag by its name (its label is refined while it
stays up, ``OPEN`` becoming ``OPEN(T12)`` once STATUS names the channel), a link fault by
``STALE`` or ``DISCONNECTED``. The two scopes are updated separately, so a silent link does not
close a box fault, nor a sample a link fault.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

# flags that are the box's normal working, not a fault: not kept in the history
ROUTINE_FLAGS = frozenset({"SLEW", "REFERENCED"})
SAMPLE, LINK = "sample", "link"
KEEP = 200  # entries kept (the oldest closed ones go first)


@dataclass
class FaultEntry:
    """One fault from when it came up until it cleared (``cleared`` None: still active)."""

    key: str
    label: str
    scope: str
    since: float  # host time (time.time())
    since_seq: int | None
    cleared: float | None = None
    cleared_seq: int | None = None

    @property
    def active(self) -> bool:
        return self.cleared is None

    def duration_s(self, now: float) -> float:
        return (self.cleared if self.cleared is not None else now) - self.since

    def as_json(self) -> dict:
        return {"fault": self.label, "key": self.key, "scope": self.scope,
                "since_unix_s": round(self.since, 3), "since_seq": self.since_seq,
                "cleared_unix_s": None if self.cleared is None else round(self.cleared, 3),
                "cleared_seq": self.cleared_seq}


def clock(t: float) -> str:
    """A host time as the wall clock (local HH:MM:SS)."""
    return time.strftime("%H:%M:%S", time.localtime(t))


def duration_text(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.1f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


class FaultHistory:
    """Open and closed fault entries, oldest first."""

    def __init__(self, keep: int = KEEP) -> None:
        self.keep = keep
        self.entries: list[FaultEntry] = []

    def active(self, scope: str | None = None) -> list[FaultEntry]:
        return [e for e in self.entries if e.active and (scope is None or e.scope == scope)]

    def update(self, scope: str, labels: Mapping[str, str], now: float,
               seq: int | None = None) -> list[tuple[str, FaultEntry]]:
        """Make ``labels`` (key -> label) the active faults of ``scope``: open the new ones,
        refine the labels of those still up, close the rest. Returns the changes as
        ("fault" | "cleared", entry)."""
        changes: list[tuple[str, FaultEntry]] = []
        open_ = {e.key: e for e in self.active(scope)}
        for key, entry in open_.items():
            if key not in labels:
                entry.cleared, entry.cleared_seq = now, seq
                changes.append(("cleared", entry))
            elif labels[key] != entry.label and "(" in labels[key]:
                entry.label = labels[key]  # more specific now (STATUS named the channel)
        for key, label in labels.items():
            if key not in open_:
                entry = FaultEntry(key, label, scope, now, seq)
                self.entries.append(entry)
                changes.append(("fault", entry))
        self._trim()
        return changes

    def open(self, scope: str, key: str, label: str, now: float,
             seq: int | None = None) -> list[tuple[str, FaultEntry]]:
        """Open one fault of ``scope`` (if it is not open already), leaving the others."""
        if any(e.key == key for e in self.active(scope)):
            return []
        labels = {e.key: e.label for e in self.active(scope)} | {key: label}
        return self.update(scope, labels, now, seq)

    def close(self, scope: str, key: str, now: float,
              seq: int | None = None) -> list[tuple[str, FaultEntry]]:
        """Close one fault of ``scope`` (if open), leaving the others."""
        labels = {e.key: e.label for e in self.active(scope) if e.key != key}
        return self.update(scope, labels, now, seq)

    def _trim(self) -> None:
        while len(self.entries) > self.keep:
            closed = next((i for i, e in enumerate(self.entries) if not e.active), 0)
            del self.entries[closed]

    def lines(self, now: float, limit: int | None = None) -> list[str]:
        """Newest first: "12:03:10 #812  OPEN(T12)  cleared 12:03:50 #852 after 40.0 s"."""
        out = []
        for e in sorted(self.entries, key=lambda e: e.since, reverse=True):
            at = f"{clock(e.since)}" + (f" #{e.since_seq}" if e.since_seq is not None else "")
            if e.active:
                end = f"ACTIVE for {duration_text(e.duration_s(now))}"
            else:
                assert e.cleared is not None
                seq = f" #{e.cleared_seq}" if e.cleared_seq is not None else ""
                end = f"cleared {clock(e.cleared)}{seq} after {duration_text(e.duration_s(now))}"
            out.append(f"{at:<18} {e.label:<24} {end}")
            if limit is not None and len(out) >= limit:
                break
        return out


def sample_fault_labels(flags: Iterable[str], labelled: Iterable[str]) -> dict[str, str]:
    """Key -> label for the non-routine flags of a sample; ``labelled`` are the same flags as
    the monitor names them (``OPEN(T12)``, ``HOLD(dz_um)``), in the same order."""
    return {f: label for f, label in zip(flags, labelled, strict=True)
            if f not in ROUTINE_FLAGS}
