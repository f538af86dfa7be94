"""`host fleet export MACHINE --since ... -o run.csv`: a machine's service log as a run.

The run format `host train`/`host evaluate` read (host.io.write_run): ``time_s`` from the box's
``seq`` times its period (so a lost line is a missing row, which the loader's ``--fill-gaps``
interpolates, never a time jump), one column per thermocouple (°C as the box read it; empty
for a faulted channel), ``corr_<axis>`` (the box's correction, µm) and, when the box reported
probe answers, ``probe_<axis>``: the drift the probe measured (correction + residual), empty
between touches (docs/service.md's logged-probe columns).

One run is one continuous stretch of one box with one model: a power-up (``seq`` starting
again), a changed model hash, period or channel list ends it. The export writes the latest
such stretch since ``--since`` and says what it left out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from thermal_comp.host.fleet.store import Store
from thermal_comp.host.fleet.topics import FleetError
from thermal_comp.host.io import write_run


@dataclass(frozen=True)
class Export:
    path: Path
    rows: int
    missing_rows: int
    left_out: int
    probes: int
    model_hash: str | None
    first_t: float
    last_t: float


def parse_since(text: str, now: float) -> float:
    """``--since``: an ISO date/time (local time), ``24h``/``90min``/``2d`` ago, or unix
    seconds."""
    text = text.strip()
    units = {"s": 1, "min": 60, "m": 60, "h": 3600, "d": 86400}
    for unit in sorted(units, key=len, reverse=True):
        if text.endswith(unit):
            try:
                return now - float(text[: -len(unit)]) * units[unit]
            except ValueError:
                break
    try:
        return float(text)
    except ValueError:
        pass
    try:
        return datetime.fromisoformat(text).timestamp()
    except ValueError:
        raise FleetError(f"--since {text!r}: use an ISO date/time (2025-03-01 or "
                         "2025-03-01T06:00), a duration ago (24h, 90min, 2d) or unix seconds"
                         ) from None


def _layout(s: dict[str, Any]) -> tuple:
    return (s["model_hash"], s["period_ms"], tuple(s["corrections_um"]),
            tuple(s["temperatures_c"]))


def export_run(store: Store, machine: str, since: float, path: str | Path,
               until: float | None = None) -> Export:
    samples = store.samples(machine, since, until)
    if not samples:
        known = [m.name for m in store.machines()]
        raise FleetError(f"no samples of {machine!r} since {since:.0f}"
                         + ("" if machine in known else
                            f" (not a machine of this fleet: {', '.join(known) or 'none'})"))
    # the latest continuous stretch: same layout, seq increasing
    start = 0
    for i in range(1, len(samples)):
        a, b = samples[i - 1], samples[i]
        if b["seq"] < a["seq"] or _layout(a) != _layout(b):
            start = i
    stretch = samples[start:]
    left_out = start
    if stretch[0]["period_ms"] is None:
        raise FleetError(f"{machine}: its gateway never had the box's INFO answer (no period, "
                         "no names): the samples cannot be timed")
    period_s = stretch[0]["period_ms"] / 1000.0
    by_seq: dict[int, dict[str, Any]] = {}
    for s in stretch:
        by_seq.setdefault(s["seq"], s)  # the same seq twice (a gateway restart): once
    seq0, seq1 = min(by_seq), max(by_seq)
    n = seq1 - seq0 + 1
    axes = list(stretch[0]["corrections_um"])
    chans = list(stretch[0]["temperatures_c"])
    cols: dict[str, np.ndarray] = {c: np.full(n, math.nan) for c in chans}
    cols.update({f"corr_{a}": np.full(n, math.nan) for a in axes})
    probe_cols = {a: np.full(n, math.nan) for a in axes}
    probes = 0
    last_probe_t = None
    for seq, s in sorted(by_seq.items()):
        i = seq - seq0
        for c, v in s["temperatures_c"].items():
            if v is not None:
                cols[c][i] = v
        for a, v in s["corrections_um"].items():
            if v is not None:
                cols[f"corr_{a}"][i] = v
        probe = s["probe"]
        if probe and probe.get("t") != last_probe_t:
            last_probe_t = probe.get("t")
            for a, r in (probe.get("residual_um") or {}).items():
                v = s["corrections_um"].get(a)
                if a in probe_cols and r is not None and v is not None:
                    probe_cols[a][i] = v + r
                    probes += 1
    for a, values in probe_cols.items():
        if np.isfinite(values).any():
            cols[f"probe_{a}"] = values
    time_s = np.arange(n) * period_s
    write_run(path, time_s, cols)
    return Export(Path(path), n, n - len(by_seq), left_out, probes, stretch[0]["model_hash"],
                  stretch[0]["t"], stretch[-1]["t"])
