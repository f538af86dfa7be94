"""`host train` speed and memory: 64 sensors x 86,400 rows (24 h at 1 s) and 600 rows.

Targets: the large run in under 10 s and 1 GB on a 2-core machine, the small one in
under 1 s. `host train` is timed in fresh processes (interpreter start and CSV parsing
included; the fastest of ``REPEAT``, every run shown), once with codegen and the effects
search off (selection + fit + validation) and once as a user runs it by default (effects +
codegen); its peak resident memory comes from its own rusage (``os.wait4`` in a small
launcher, see LAUNCHER). The EC step is timed alone for c = 10 groups (1,023 subset fits,
each from Gram matrices).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from host.io import Run, write_run
from host.selection import GramCache, ec_reduction, fold_labels
from host.train import train_model

SOURCES_TAU_S = (300.0, 1200.0, 4000.0, 9000.0)


def synthetic_run(n_rows: int, n_sensors: int, period_s: float = 1.0, seed: int = 0
                  ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Sensors driven by four heat paths of different time constants (seeded)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_rows) * period_s
    power = (np.sin(2 * np.pi * t / 7200.0) > 0).astype(float)
    srcs = []
    for tau in SOURCES_TAU_S:
        a = -np.expm1(-period_s / tau)
        srcs.append(lfilter([a], [1.0, a - 1.0], power))
    cols = {f"T{i + 1:02d}": 20 + 5 * srcs[i % 4] * (0.5 + rng.random())
            + 0.05 * rng.normal(size=n_rows) for i in range(n_sensors)}
    cols["dz_um"] = 3 * srcs[0] - 2 * srcs[2] + srcs[3] + 0.1 * rng.normal(size=n_rows)
    return t, cols


# Linux carries the old address space's high-water mark into ru_maxrss across fork + exec, so
# a process started straight from this (by now large) bench process would report the bench's
# memory. A small launcher starts the command instead and reports its wait4 rusage.
LAUNCHER = r"""
import json, os, sys, time
t0 = time.perf_counter()
pid = os.fork()
if pid == 0:
    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
    os.execvp(sys.argv[1], sys.argv[1:])
_, status, usage = os.wait4(pid, 0)
print(json.dumps({"seconds": time.perf_counter() - t0, "maxrss_kb": usage.ru_maxrss,
                  "exit": os.waitstatus_to_exitcode(status)}))
"""


REPEAT = 3  # fresh processes per timed command: the fastest is reported, every one shown


@dataclass(frozen=True)
class Timing:
    """Wall times of ``REPEAT`` fresh processes and the largest peak RSS (MB) among them.

    The fastest run is the figure (as ``timeit`` reports it): a shared 2-core VM's speed
    varies twofold within minutes (docs/selection.md section 7), and interference only ever
    adds time. The others are shown beside it, so the spread is not hidden."""

    seconds: tuple[float, ...]
    peak_mb: float

    @property
    def fastest(self) -> float:
        return min(self.seconds)

    def describe(self) -> str:
        return (f"fastest of {len(self.seconds)} fresh processes "
                f"({', '.join(f'{s:.2f}' for s in self.seconds)} s)")


def _one_process(cmd: list[str]) -> tuple[float, float]:
    """Wall time and peak RSS (MB) of one fresh process (its own rusage, via the launcher)."""
    done = subprocess.run([sys.executable, "-c", LAUNCHER, *cmd], capture_output=True,
                          text=True)
    try:
        m = json.loads(done.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        raise RuntimeError(f"launcher failed: {done.stderr[-2000:]}") from None
    if m["exit"] != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {done.stderr[-2000:]}")
    return m["seconds"], m["maxrss_kb"] / 1024.0


def timed_process(cmd: list[str], repeat: int = REPEAT) -> Timing:
    """``cmd`` run ``repeat`` times, each in a fresh process (see Timing)."""
    runs = [_one_process(cmd) for _ in range(repeat)]
    return Timing(tuple(dt for dt, _ in runs), max(peak for _, peak in runs))


def _timed_rows(cmd: list[str], name: str, rss_name: str, target_s: float,
                detail: str) -> list[dict]:
    """The time row (against ``target_s``) and the peak-memory row of ``cmd``, timed."""
    timing = timed_process(cmd)
    return [{"name": name, "value": timing.fastest, "unit": "s", "target": f"< {target_s:g} s",
             "detail": f"{detail}; {timing.describe()}"},
            {"name": rss_name, "value": timing.peak_mb, "unit": "MB", "target": "< 1024 MB"}]


def run() -> list[dict]:
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        for n_rows, target in ((600, 1.0), (86_400, 10.0)):
            t, cols = synthetic_run(n_rows, 64)
            csv = tmpdir / f"run_{n_rows}.csv"
            write_run(csv, t, cols)
            train = [sys.executable, "-m", "host", "train", str(csv), "--target", "dz_um",
                     "--json", "--out"]
            rows += _timed_rows([*train, str(tmpdir / f"out_{n_rows}"), "--no-codegen",
                                 "--no-effects"],
                                f"host train, 64 sensors x {n_rows} rows",
                                f"host train peak RSS, 64 x {n_rows} rows", target,
                                "host train --no-effects --no-codegen: CSV parse + selection + "
                                "fit + validation")
            # the default a user runs: effects search and codegen included
            rows += _timed_rows([*train, str(tmpdir / f"full_{n_rows}")],
                                f"host train (default: effects + codegen), 64 x {n_rows}",
                                f"host train (default) peak RSS, 64 x {n_rows}", target,
                                "what `host train RUN.csv --target dz_um` costs")
            names = [c for c in cols if c.startswith("T")]
            mem = Run(str(csv), t, names, np.column_stack([cols[c] for c in names]), ["dz_um"],
                      cols["dz_um"][:, None])
            t0 = time.perf_counter()
            train_model([mem], ["dz_um"], effects=False)
            rows.append({"name": f"train_model in memory, 64 x {n_rows}",
                         "value": time.perf_counter() - t0, "unit": "s",
                         "detail": "selection + fit + validation, data already loaded"})
        # EC alone: c = 10 representatives, 1,023 subsets, out-of-fold error
        t, cols = synthetic_run(86_400, 10)
        X = np.column_stack([cols[f"T{i + 1:02d}"] for i in range(10)])
        y = cols["dz_um"]
        t0 = time.perf_counter()
        cache = GramCache(X, y, fold_labels(np.zeros(len(y))))
        t_gram = time.perf_counter() - t0
        t0 = time.perf_counter()
        ec_reduction(cache, list(range(10)), "validation", 5)
        rows.append({"name": "EC over 1,023 subsets (c=10), out-of-fold",
                     "value": time.perf_counter() - t0, "unit": "s",
                     "detail": f"Gram matrices built once in {t_gram:.3f} s"})
    return rows


if __name__ == "__main__":
    for row in run():
        print(row)
