"""HIL throughput: replay 24 h of 1 s data (86,400 samples, 5 sensors, 3 axes) through the
native firmware over its pty and check every line (target: under 30 s).

The run comes from ``host simulate`` (random spindle program) when that command exists,
otherwise it is synthesised here (seeded smooth temperature walks and a spindle program; the
displacements are a linear response plus noise): the HIL's speed does not depend on how
realistic the physics is.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.goal import INFO, goal
from thermal_comp.hil import replay as hil_replay
from thermal_comp.hil.example_model import default_terms, fit_example_model, write_model
from thermal_comp.host.io import write_run

N_SAMPLES = 86_400
SENSORS = [f"T{i:02d}" for i in range(1, 6)]
AXES = ["dx_um", "dy_um", "dz_um"]


def synthesise(path: Path, n: int = N_SAMPLES, seed: int = 24) -> Path:
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    rpm = np.zeros(n)
    for start in range(0, n, 7200):  # 2 h blocks: run 1 h at a random speed, rest 1 h
        rpm[start:start + 3600] = rng.choice([2000, 4000, 6000, 8000])
    cols: dict[str, np.ndarray] = {}
    heat = np.convolve(rpm / 8000.0, np.exp(-np.arange(4 * 3600) / 1800.0), "full")[:n] / 1800
    for i, name in enumerate(SENSORS):
        drift = np.cumsum(rng.normal(0, 0.002, n))
        cols[name] = 22.0 + (2 + i) * heat + drift
    for k, name in enumerate(AXES):
        w = rng.normal(0, 2.0, len(SENSORS))
        cols[name] = sum(w[i] * (cols[s] - 22.0) for i, s in enumerate(SENSORS)) * (1 + k) \
            + rng.normal(0, 0.2, n)
    cols["spindle_rpm"] = rpm
    write_run(path, t, cols, precision=8)
    return path


def simulated_run(path: Path) -> tuple[Path, str]:
    """A 24 h 1 s run: ``host simulate`` (16 h running + 8 h cooling), else synthesised."""
    proc = subprocess.run([sys.executable, "-m", "thermal_comp.host", "simulate", "--protocol",
                           "random",
                           "--hours", "16", "--cool-hours", "8", "--dt", "1", "--sensors", "5",
                           "--seed", "24", "-o", str(path)], capture_output=True, text=True)
    if proc.returncode != 0 or not path.is_file():
        return synthesise(path), f"synthesised (host simulate failed: {proc.stderr.strip()})"
    return path, "host simulate --protocol random"


def run() -> list[dict]:
    with tempfile.TemporaryDirectory(prefix="bench_hil_") as tmp:
        d = Path(tmp)
        data, source = simulated_run(d / "run24h.csv")
        with data.open() as fh:
            header = fh.readline().strip().split(",")
        sensors = [c for c in header if c.startswith("T")][:5]
        axes = [c for c in header if c.endswith("_um")][:3]
        aux = "spindle_rpm" if "spindle_rpm" in header else None
        terms = default_terms(sensors, 1.0, aux)
        model = fit_example_model(data, {a: terms for a in axes}, aux_names=[aux] if aux else [])
        model_path = write_model(model, d / "model.json")
        t0 = time.perf_counter()
        setup = hil_replay.prepare(model_path, data, d / "hil")
        t_prepare = time.perf_counter() - t0
        t0 = time.perf_counter()
        report, _ = hil_replay.run(setup)
        total = time.perf_counter() - t0
    detail = (f"{report.samples} samples ({source}), {len(sensors)} sensors, {len(axes)} axes; "
              f"checks {'passed' if report.ok else 'FAILED: ' + '; '.join(report.problems[:3])}")
    return [
        {"name": "HIL replay 24 h @ 1 s: feed + lines", "value": report.elapsed_s,
         "unit": "s", "target": "< 30 s", "goal": goal("<", 30), "detail": detail},
        {"name": "HIL replay 24 h @ 1 s: incl. checks", "value": total, "unit": "s",
         "target": "< 30 s", "goal": goal("<", 30),
         "detail": "replay plus twin, float model and residuals"},
        {"name": "HIL replay throughput", "value": report.samples / report.elapsed_s,
         "unit": "samples/s", "goal": INFO, "detail": detail},
        {"name": "HIL header + native build + load run", "value": t_prepare, "unit": "s",
         "goal": INFO},
        {"name": "HIL twin mismatches (24 h)", "value": report.mismatches, "unit": "samples",
         "target": "0", "goal": goal("==", 0)},
    ]


if __name__ == "__main__":
    for row in run():
        print(row)
