"""Simulator speed: 24 h of 64 thermocouples at 1 s (target: under 10 s)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from bench.goal import goal
from thermal_comp.host.sim import EFFECTS, SimConfig, build_program, simulate, write_simulation


def run() -> list[dict]:
    rows = []
    for protocol in ("constant", "random", "sine"):
        program = build_program(protocol, 8000.0, hours=16.0, cool_hours=8.0, seed=1)
        config = SimConfig(n_sensors=64, dt_s=1.0, seed=1, effects=EFFECTS)
        t0 = time.perf_counter()
        sim = simulate(program, config)
        t1 = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "run.csv"
            write_simulation(sim, path)
            size_mb = path.stat().st_size / 1e6
        t2 = time.perf_counter()
        detail = (f"{sim.time_s.size} samples x {len(sim.sensor_names)} temperatures, "
                  f"all effects, {protocol} (16 h + 8 h cooling)")
        rows.append({"name": f"simulate 24h x 64 @1s ({protocol})", "value": t1 - t0,
                     "unit": "s", "target": "< 10 s", "goal": goal("<", 10),
                     "detail": detail})
        rows.append({"name": f"simulate + write CSV/truth ({protocol})", "value": t2 - t0,
                     "unit": "s", "target": "< 10 s", "goal": goal("<", 10),
                     "detail": f"CSV {size_mb:.0f} MB"})
    return rows
