"""The model learns from weeks of probes (issue 42, `host train --service LOG.csv`).

On the project's simulator, per machine: train on day 1 (a step program), serve days 2-5
(random, sine, constant and random programs in a shop 2-5 degC warmer or cooler, starting at
other hours), where a probe touches every 60 min with 0.5 um noise and the service log keeps
the box's channels and the readings; test on day 6 (a random program on another day). The
same day-1 training with and without ``--service`` (the four logs), each judged on day 6 by
``host evaluate``: static (the model alone) and updated (the in-service estimator with the
same probe plan on day 6). Rows: geometric means of refit / plain over machines and axes, and
the worst single case. Writes the table to stdout; ``python -m bench refit``.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from bench.goal import INFO, goal

MACHINES = (3, 5, 8)
TARGETS = ("dx_um", "dy_um", "dz_um")
# day -> (program, seed, shop air at the start degC, start hour)
DAYS = {1: ("step", 11, 20.0, 7.0), 2: ("random", 12, 23.0, 6.0), 3: ("sine", 13, 17.0, 9.0),
        4: ("constant", 14, 24.0, 5.0), 5: ("random", 15, 18.0, 8.0),
        6: ("random", 16, 22.0, 7.0)}
PROBE_EVERY_S, PROBE_NOISE_UM = 3600.0, 0.5


def host(*args: str) -> str:
    done = subprocess.run([sys.executable, "-m", "thermal_comp.host", "-q", *args],
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"host {' '.join(args)}: {done.stderr.strip()}")
    return done.stdout


def simulate_day(d: Path, machine: int, day: int) -> Path:
    program, seed, ambient, hour = DAYS[day]
    out = d / f"m{machine}_day{day}.csv"
    host("simulate", "--protocol", program, "--seed", str(seed), "--machine-seed", str(machine),
         "--ambient-c", str(ambient), "--start-hour", str(hour), "--hours", "8",
         "--cool-hours", "8", "--effects", "ambient", "-o", str(out))
    return out


def service_log(run_csv: Path, model_json: Path, seed: int) -> Path:
    """What the box and the probe would have logged that day: the model's channels and
    aux inputs, and every 60 min each axis's displacement since the reference plus noise."""
    from thermal_comp.host.analysis.evaluate import measured
    from thermal_comp.host.io import load_run
    from thermal_comp.host.service import ProbePlan, probe_column, synthesise_probes

    model = json.loads(model_json.read_text())
    sensors = [c["sensor"] for c in model["channels"]]
    aux = [a["name"] for a in model.get("aux", [])]
    run = load_run(run_csv, list(model["axes"]), sensors, aux)
    truth = {a: measured(model, run, a) for a in model["axes"]}  # referenced as the model is
    readings = synthesise_probes(run, truth, ProbePlan(PROBE_EVERY_S, PROBE_NOISE_UM, seed))
    out = run_csv.with_name(run_csv.stem + "_service.csv")
    cols = run.columns()
    names = ["time_s", *sensors, *aux, *(probe_column(a) for a in model["axes"])]
    with out.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        probe = {a: dict(zip(readings.index[a].tolist(), readings.value[a].tolist(),
                             strict=True)) for a in model["axes"]}
        for k in range(run.n_samples):
            w.writerow([f"{run.time_s[k]:g}", *(f"{cols[s][k]:.4f}" for s in [*sensors, *aux]),
                        *(f"{probe[a][k]:.4f}" if k in probe[a] else "" for a in model["axes"])])
    return out


def judge(model_json: Path, test: Path) -> dict[str, tuple[float, float]]:
    """axis -> (static, updated) RMSE on the test day."""
    doc = json.loads(host("evaluate", str(model_json), str(test), "--probe-every",
                          f"{PROBE_EVERY_S:g}s", "--probe-noise-um", f"{PROBE_NOISE_UM:g}",
                          "--json"))
    axes = doc["runs"][0]["axes"] if "runs" in doc else doc["axes"]
    return {a: (m["static_rmse_um"], m["rmse_um"]) for a, m in axes.items()}


def machine_cases(machine: int, d: Path) -> list[dict]:
    days = {k: simulate_day(d, machine, k) for k in DAYS}
    targets = [x for t in TARGETS for x in ("--target", t)]
    plain = d / f"m{machine}_plain"
    host("train", str(days[1]), *targets, "--out", str(plain), "--no-nested")
    logs = [service_log(days[k], plain / "model.json", seed=k) for k in (2, 3, 4, 5)]
    refit = d / f"m{machine}_refit"
    host("train", str(days[1]), *targets, "--out", str(refit), "--no-nested",
         "--service", *map(str, logs))
    before, after = judge(plain / "model.json", days[6]), judge(refit / "model.json", days[6])
    return [{"machine": machine, "axis": a, "plain_static": before[a][0],
             "plain_updated": before[a][1], "refit_static": after[a][0],
             "refit_updated": after[a][1]} for a in before]


def gmean(x: list[float]) -> float:
    return float(math.exp(np.mean(np.log(x))))


def run() -> list[dict]:
    with tempfile.TemporaryDirectory() as tmp:
        cases = [c for m in MACHINES for c in machine_cases(m, Path(tmp))]
    for c in cases:
        print(f"  machine {c['machine']} {c['axis']}: static {c['plain_static']:.3f} -> "
              f"{c['refit_static']:.3f} um, updated {c['plain_updated']:.3f} -> "
              f"{c['refit_updated']:.3f} um", file=sys.stderr)
    static = [c["refit_static"] / c["plain_static"] for c in cases]
    updated = [c["refit_updated"] / c["plain_updated"] for c in cases]
    plain_upd = [c["plain_updated"] / c["plain_static"] for c in cases]
    return [
        {"name": "service refit, static on day 6: refit / plain (geometric mean)",
         "value": gmean(static), "unit": "x", "goal": goal("<", 1.0),
         "detail": {"cases": cases}},
        {"name": "service refit, updated on day 6: refit / plain", "value": gmean(updated),
         "unit": "x", "goal": goal("<=", 1.0)},
        {"name": "service refit, worst single case (static)", "value": max(static),
         "unit": "x", "goal": INFO},
        {"name": "plain model, updated / static on day 6", "value": gmean(plain_upd),
         "unit": "x", "goal": INFO},
    ]


if __name__ == "__main__":
    for row in run():
        print(f"{row['name']:<66} {row['value']:.3f} {row['unit']}")
