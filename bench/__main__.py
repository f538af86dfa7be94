"""Run bench/bench_*.py (all, or the suites named), print a table, merge bench/results/bench.json.

Each module defines ``run() -> list[dict]``; a row has ``name``, ``value``, ``unit``, a
machine-checkable ``goal`` (bench/goal.py: ``{"op": "<=", "value": 10}``, or ``INFO`` for a
row that only informs), and optionally ``target`` (the goal in words, "< 10 s on 2 cores")
and ``detail``. The table shows each row's result: ``pass``, ``FAIL``, ``info`` (not
counted), or ``NO GOAL`` (a row without one: counted as a failure); one summary line ends it.

Results are merged: the rows of the suites run replace those suites' rows in bench.json, the
other suites' rows stay as their last run left them (each suite's date, commit and machine in
``suites``), so ``python -m bench train`` does not wipe ``make bench``'s accuracy numbers.

Exit status: 0 when every suite ran, whatever the results (the numbers are the output: a
timing target missed on a busy shared machine is reported, not an error); ``--strict``: 1
when any row fails; 2 for a name that is no suite. A suite that crashes stops the run with its
traceback (status 1); the suites before it are already merged into bench.json.

A module may name options the runner passes on (``RUNNER_FLAGS``; then ``run(flags)``):
``python -m bench promise --quick``. Any other option is refused: a suite's own options go to
its module (``python -m bench.bench_accuracy --help``).
"""

from __future__ import annotations

import datetime
import importlib
import json
import pkgutil
import platform
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import bench
from bench.goal import target_text, verdict

RESULTS = Path(__file__).parent / "results" / "bench.json"
NAME_WIDTH = 50  # longer names wrap onto the next lines; the other columns stay put
UNIT_WIDTH = 9
SHOWN = {"pass": "pass", "fail": "FAIL", "info": "info", "no goal": "NO GOAL"}


def _commit() -> str:
    done = subprocess.run(["git", "describe", "--always", "--dirty"], capture_output=True,
                          text=True, cwd=Path(__file__).parent)
    return done.stdout.strip() if done.returncode == 0 else "unknown"


def format_row(row: dict, suite_width: int) -> list[str]:
    """The row's line(s) in the table: a name longer than NAME_WIDTH (or a unit longer than
    UNIT_WIDTH) continues on the next line(s) in its own column."""
    names = textwrap.wrap(str(row["name"]), NAME_WIDTH) or [""]
    units = textwrap.wrap(str(row.get("unit", "")), UNIT_WIDTH) or [""]
    try:
        value = f"{float(row['value']):>11.4g}"
    except (TypeError, ValueError):
        value = f"{str(row['value'])[:11]:>11}"
    target = row.get("target") or target_text(row.get("goal") or {}, "")
    lines = [f"  {row['suite']:<{suite_width}} {names[0]:<{NAME_WIDTH}} {value} "
             f"{units[0]:<{UNIT_WIDTH}} {SHOWN[row['result']]:<7} {target}".rstrip()]
    for k in range(1, max(len(names), len(units))):
        name = names[k] if k < len(names) else ""
        unit = units[k] if k < len(units) else ""
        lines.append(f"  {'':<{suite_width}} {name:<{NAME_WIDTH}} {'':>11} {unit}".rstrip())
    return lines


def summary(rows: list[dict]) -> str:
    """One line: N pass, M fail, K info, and the failing rows by name."""
    count = {k: sum(r["result"] == k for r in rows) for k in SHOWN}
    failing = [r for r in rows if r["result"] in ("fail", "no goal")]
    line = (f"bench: {count['pass']} pass, {len(failing)} fail, {count['info']} info "
            f"({len(rows)} rows)")
    if failing:
        line += "; failing: " + "; ".join(
            f"{r['suite']}: {r['name']}" + (" (no goal)" if r["result"] == "no goal" else "")
            for r in failing)
    return line


def merge(path: Path, suites_run: dict[str, dict], rows: list[dict]) -> dict:
    """bench.json with these suites' rows replaced and every other suite's kept."""
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError):
        old = {}
    kept = [r for r in old.get("rows", []) if r.get("suite") not in suites_run]
    suites = {k: v for k, v in old.get("suites", {}).items() if k not in suites_run}
    if "suites" not in old:  # a bench.json from before the merge: its machine for its rows
        for r in kept:
            suites.setdefault(r.get("suite", "?"), {"machine": old.get("machine"),
                                                    "python": old.get("python")})
    suites.update(suites_run)
    order = sorted(suites)
    merged = sorted(kept + rows, key=lambda r: order.index(r["suite"])
                    if r.get("suite") in order else len(order))
    return {"machine": platform.platform(), "python": platform.python_version(),
            "suites": dict(sorted(suites.items())), "rows": merged}


def main(argv: list[str] | None = None) -> int:
    only = list(sys.argv[1:] if argv is None else argv)
    strict = "--strict" in only
    only = [a for a in only if a != "--strict"]
    suites = sorted(m.name.removeprefix("bench_") for m in pkgutil.iter_modules(bench.__path__)
                    if m.name.startswith("bench_"))
    # a suite's RUNNER_FLAGS (e.g. promise's --quick) go to its run(); any other option is
    # refused below
    allowed = {f for n in only if n in suites
               for f in getattr(importlib.import_module(f"bench.bench_{n}"), "RUNNER_FLAGS", ())}
    flags = [a for a in only if a in allowed]
    only = [a for a in only if a not in allowed]
    unknown = [a for a in only if a not in suites]
    if unknown:  # a suite's own options go to its module: python -m bench.bench_accuracy ...
        print(f"bench: not a suite: {' '.join(unknown)} (suites: {', '.join(suites)}; a "
              f"suite's options: python -m bench.bench_<suite> --help; the runner's: "
              f"--strict)", file=sys.stderr)
        return 2
    chosen = [n for n in suites if not only or n in only]
    width = max(len(n) for n in chosen)
    commit = _commit()
    rows: list[dict] = []
    for name in chosen:
        mod = importlib.import_module(f"bench.bench_{name}")
        t0 = time.perf_counter()
        mine = [f for f in flags if f in getattr(mod, "RUNNER_FLAGS", ())]
        got = list(mod.run(mine) if mine else mod.run())
        seconds = time.perf_counter() - t0
        for row in got:
            row.setdefault("suite", name)
            row["result"] = verdict(row)
            print("\n".join(format_row(row, width)), flush=True)
        print(f"  (bench_{name} took {seconds:.1f} s)", flush=True)
        rows += got
        ran = {name: {"when": datetime.datetime.now().isoformat(timespec="seconds"),
                      "commit": commit, "machine": platform.platform(),
                      "python": platform.python_version(), "seconds": round(seconds, 1),
                      "flags": mine}}
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(json.dumps(merge(RESULTS, ran, got), indent=2))
    print(summary(rows))
    print(f"merged into {RESULTS} (suites run: {', '.join(chosen)})")
    return 1 if strict and any(r["result"] in ("fail", "no goal") for r in rows) else 0


if __name__ == "__main__":
    raise SystemExit(main())
