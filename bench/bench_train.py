"""`host train` speed and memory: 64 sensors x 86,400 rows (24 h at 1 s), its scaling, 600 rows.

Targets (bench/goal.py): the main case in at most 10 s and 1 GB on a 2-core machine; at most
3x the floor (reading the same CSV with ``numpy.loadtxt`` and one ``np.linalg.lstsq`` on 5
sensors, in a fresh process: what any program that reads this file and fits it pays); time
per (rows x sensors) at 4x the rows (64 x 345,600) and at twice the sensors (128 x 86,400)
at most 1.3x the main case's (linear scaling); 600 rows in at most 1 s.

Every command is timed in fresh processes (interpreter start and CSV parsing included; the
fastest of ``REPEAT``, every run shown), once with codegen and the effects search off
(selection + fit + validation) and once as a user runs it by default (effects + codegen).

Memory is that of every process the command starts: ``host train`` can fork workers for its
nested folds (``--jobs N``, host/parallel.py; by default since ca1e363 it does not), each with
its own address space. A small launcher
(LAUNCHER) starts the command and, every ``BENCH_SAMPLE_S`` (0.05 s) while it runs, sums the
proportional set size (``Pss`` of /proc/PID/smaps_rollup; ``VmRSS`` where the kernel has no
rollup) over the command's process and all its descendants; the peak of that sum is the
figure. PSS divides each page shared after fork among the processes sharing it, so the sum is
the memory the tree occupies, not a multiple of the parent's. A peak shorter than a sample
can slip between two: the figure is never below the largest single process's own peak RSS
(``ru_maxrss`` of RUSAGE_CHILDREN), which the detail shows beside the peak of summed RSS.

The EC step is timed alone for c = 10 groups (1,023 subset fits, each from Gram matrices).
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

from bench.goal import INFO, goal
from thermal_comp.host.io import Run, write_run
from thermal_comp.host.selection import GramCache, ec_reduction, fold_labels
from thermal_comp.host.train import train_model

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
# memory. A small launcher starts the command instead, samples the memory of the command's
# process tree while it runs (the module's docstring) and reports it with its rusage.
LAUNCHER = r"""
import json, os, resource, sys, threading, time

SAMPLE_S = float(os.environ.get("BENCH_SAMPLE_S", "0.05"))
ROLLUP = os.path.exists("/proc/self/smaps_rollup")


def tree(root):
    # root and its descendants, from the parent pid in every /proc/PID/stat
    kids = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as f:
                    stat = f.read()
            except OSError:
                continue
            kids.setdefault(int(stat[stat.rindex(")") + 2:].split()[1]), []).append(int(d))
    out, todo = [], [root]
    while todo:
        p = todo.pop()
        out.append(p)
        todo += kids.get(p, [])
    return out


def field_kb(path, name):
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(name):
                    return int(line.split()[1])
    except OSError:  # the process ended between the listing and the read
        pass
    return 0


peak = {"pss_kb": 0, "rss_kb": 0, "procs": 0, "samples": 0}
done = threading.Event()


def sample(root):
    while not done.is_set():
        pids = tree(root)
        rss = sum(field_kb(f"/proc/{p}/status", "VmRSS:") for p in pids)
        pss = (sum(field_kb(f"/proc/{p}/smaps_rollup", "Pss:") for p in pids) if ROLLUP
               else rss)
        peak["pss_kb"] = max(peak["pss_kb"], pss)
        peak["rss_kb"] = max(peak["rss_kb"], rss)
        peak["procs"] = max(peak["procs"], len(pids))
        peak["samples"] += 1
        done.wait(SAMPLE_S)


t0 = time.perf_counter()
pid = os.fork()
if pid == 0:
    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
    os.execvp(sys.argv[1], sys.argv[1:])
sampler = threading.Thread(target=sample, args=(pid,), daemon=True)
sampler.start()
_, status, usage = os.wait4(pid, 0)
seconds = time.perf_counter() - t0
done.set()
sampler.join()
largest = max(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, usage.ru_maxrss)
print(json.dumps({"seconds": seconds, "sum_pss_kb": peak["pss_kb"], "sum_rss_kb": peak["rss_kb"],
                  "largest_kb": largest, "procs": peak["procs"], "samples": peak["samples"],
                  "exit": os.waitstatus_to_exitcode(status)}))
"""


REPEAT = 3  # fresh processes per timed command: the fastest is reported, every one shown


@dataclass(frozen=True)
class Timing:
    """Wall times of ``REPEAT`` fresh processes and the peak memory (MB) among them.

    The fastest run is the figure (as ``timeit`` reports it): a shared 2-core VM's speed
    varies twofold within minutes (docs/selection.md section 7), and interference only ever
    adds time. The others are shown beside it, so the spread is not hidden. ``peak_mb``: the
    peak of the memory summed over the command's process tree (module docstring), the
    largest over the runs; ``largest_mb``: the largest single process's own peak RSS;
    ``sum_rss_mb``: the peak of the summed RSS (pages shared after fork counted once per
    process); ``procs``: the most processes alive at once."""

    seconds: tuple[float, ...]
    peak_mb: float
    largest_mb: float = 0.0
    sum_rss_mb: float = 0.0
    procs: int = 1

    @property
    def fastest(self) -> float:
        return min(self.seconds)

    def describe(self) -> str:
        return (f"fastest of {len(self.seconds)} fresh processes "
                f"({', '.join(f'{s:.2f}' for s in self.seconds)} s)")

    def describe_memory(self) -> str:
        return (f"peak of PSS summed over the process tree ({self.procs} at most at once); "
                f"largest single process {self.largest_mb:.0f} MB, peak of summed RSS "
                f"{self.sum_rss_mb:.0f} MB")


def _one_process(cmd: list[str]) -> dict:
    """Wall time and memory (MB) of one fresh process and every process it starts."""
    done = subprocess.run([sys.executable, "-c", LAUNCHER, *cmd], capture_output=True,
                          text=True)
    try:
        m = json.loads(done.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        raise RuntimeError(f"launcher failed: {done.stderr[-2000:]}") from None
    if m["exit"] != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {done.stderr[-2000:]}")
    largest = m["largest_kb"] / 1024.0
    return {"seconds": m["seconds"], "largest_mb": largest,
            "peak_mb": max(m["sum_pss_kb"] / 1024.0, largest),
            "sum_rss_mb": m["sum_rss_kb"] / 1024.0, "procs": max(1, m["procs"])}


def timed_process(cmd: list[str], repeat: int = REPEAT) -> Timing:
    """``cmd`` run ``repeat`` times, each in a fresh process (see Timing)."""
    runs = [_one_process(cmd) for _ in range(repeat)]
    return Timing(tuple(r["seconds"] for r in runs), max(r["peak_mb"] for r in runs),
                  max(r["largest_mb"] for r in runs), max(r["sum_rss_mb"] for r in runs),
                  max(r["procs"] for r in runs))


# The floor: what any program that reads this CSV and fits 5 sensors pays.
FLOOR = r"""
import sys
import numpy as np
data = np.loadtxt(sys.argv[1], delimiter=",", skiprows=1)
X = np.column_stack([np.ones(len(data)), data[:, 1:6]])
np.linalg.lstsq(X, data[:, -1], rcond=None)
"""

MAIN = (86_400, 64)  # rows, sensors
SCALING = ((345_600, 64), (86_400, 128))  # 4x the rows, twice the sensors
SCALING_REPEAT = 2  # these take 2-4x as long as the main case: two fresh processes each
LINEAR_SLACK = 1.3  # time per (rows x sensors) at most this times the main case's
NO_EFFECTS = ("--no-codegen", "--no-effects")
NO_EFFECTS_WHAT = "host train --no-effects --no-codegen: CSV parse + selection + fit + validation"


def _train_cmd(csv: Path, out: Path, *extra: str) -> list[str]:
    # --time-unit s: the 600-row run warms by degrees in 10 min, which host train would take
    # for a run logged in minutes (and refuse without the unit)
    return [sys.executable, "-m", "thermal_comp.host", "train", str(csv), "--target", "dz_um",
            "--json",
            "--time-unit", "s", "--out", str(out), *extra]


def _time_row(name: str, timing: Timing, target_s: float | None, detail: str) -> dict:
    row = {"name": name, "value": timing.fastest, "unit": "s", "goal": INFO,
           "detail": f"{detail}; {timing.describe()}"}
    if target_s is not None:
        row.update(target=f"<= {target_s:g} s", goal=goal("<=", target_s))
    return row


def _memory_row(name: str, timing: Timing, limit_mb: float | None = 1024) -> dict:
    row = {"name": name, "value": timing.peak_mb, "unit": "MB", "goal": INFO,
           "detail": timing.describe_memory()}
    if limit_mb is not None:
        row.update(target=f"<= {limit_mb:g} MB", goal=goal("<=", limit_mb))
    return row


def _write(tmpdir: Path, n_rows: int, n_sensors: int) -> tuple[Path, dict]:
    t, cols = synthetic_run(n_rows, n_sensors)
    csv = tmpdir / f"run_{n_sensors}x{n_rows}.csv"
    write_run(csv, t, cols)
    return csv, cols


def _floor_rows(csv: Path, plain: Timing, full: Timing) -> list[dict]:
    floor = timed_process([sys.executable, "-c", FLOOR, str(csv)])
    return [
        _time_row("floor: numpy.loadtxt + lstsq on 5 sensors, 64 x 86400", floor, None,
                  "a fresh process reads the same CSV and fits 5 sensors by least squares"),
        {"name": "host train (default) / floor, 64 x 86400", "value": full.fastest /
         floor.fastest, "unit": "x", "target": "<= 3x", "goal": goal("<=", 3.0),
         "detail": f"{full.fastest:.2f} s / {floor.fastest:.2f} s"},
        {"name": "host train --no-effects / floor, 64 x 86400", "value": plain.fastest /
         floor.fastest, "unit": "x", "goal": INFO,
         "detail": f"{plain.fastest:.2f} s / {floor.fastest:.2f} s"}]


def _scaling_rows(tmpdir: Path, main: Timing) -> list[dict]:
    """Selection + fit + validation (the part that grows with the data) at 4x the rows and
    twice the sensors: time per (rows x sensors) against the main case's."""
    per_cell = main.fastest / (MAIN[0] * MAIN[1])
    rows: list[dict] = []
    for n_rows, n_sensors in SCALING:
        csv, _ = _write(tmpdir, n_rows, n_sensors)
        timing = timed_process(_train_cmd(csv, tmpdir / f"out_{n_sensors}x{n_rows}",
                                          *NO_EFFECTS), repeat=SCALING_REPEAT)
        csv.unlink()
        label = f"{n_sensors} x {n_rows}"
        rows += [_time_row(f"host train, {n_sensors} sensors x {n_rows} rows", timing, None,
                           NO_EFFECTS_WHAT),
                 _memory_row(f"host train peak memory, {label} rows", timing, None),
                 {"name": f"time per row x sensor, {label} / 64 x 86400",
                  "value": timing.fastest / (n_rows * n_sensors) / per_cell, "unit": "x",
                  "target": f"<= {LINEAR_SLACK:g}x (linear)", "goal": goal("<=", LINEAR_SLACK),
                  "detail": f"{timing.fastest:.2f} s for {n_rows * n_sensors / 1e6:.1f} M "
                            f"values, {main.fastest:.2f} s for {MAIN[0] * MAIN[1] / 1e6:.1f} M "
                            "(--no-effects --no-codegen)"}]
    return rows


def run() -> list[dict]:
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        for n_rows, target in ((600, 1.0), (MAIN[0], 10.0)):
            csv, cols = _write(tmpdir, n_rows, MAIN[1])
            plain = timed_process(_train_cmd(csv, tmpdir / f"out_{n_rows}", *NO_EFFECTS))
            rows += [_time_row(f"host train, 64 sensors x {n_rows} rows", plain, target,
                               NO_EFFECTS_WHAT),
                     _memory_row(f"host train peak memory, 64 x {n_rows} rows", plain)]
            # the default a user runs: effects search and codegen included
            full = timed_process(_train_cmd(csv, tmpdir / f"full_{n_rows}"))
            rows += [_time_row(f"host train (default: effects + codegen), 64 x {n_rows}",
                               full, target, "what `host train RUN.csv --target dz_um` costs"),
                     _memory_row(f"host train (default) peak memory, 64 x {n_rows}", full)]
            names = [c for c in cols if c.startswith("T")]
            mem = Run(str(csv), np.arange(n_rows, dtype=float), names,
                      np.column_stack([cols[c] for c in names]), ["dz_um"],
                      cols["dz_um"][:, None])
            t0 = time.perf_counter()
            train_model([mem], ["dz_um"], effects=False)
            rows.append({"name": f"train_model in memory, 64 x {n_rows}",
                         "value": time.perf_counter() - t0, "unit": "s", "goal": INFO,
                         "detail": "selection + fit + validation, data already loaded"})
            if n_rows == MAIN[0]:
                rows += _floor_rows(csv, plain, full)
                main = plain
            csv.unlink()
        rows += _scaling_rows(tmpdir, main)
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
                     "value": time.perf_counter() - t0, "unit": "s", "goal": INFO,
                     "detail": f"Gram matrices built once in {t_gram:.3f} s"})
    return rows


if __name__ == "__main__":
    for row in run():
        print(row)
