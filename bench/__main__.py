"""Run every bench/bench_*.py, print one table and write bench/results/bench.json.

Each module defines ``run() -> list[dict]``; a row has at least ``name``, ``value``, ``unit``
and optionally ``target`` (a human-readable goal such as "< 10 s") and ``detail``. A module
may name options the runner passes on (``RUNNER_FLAGS``; then ``run(flags)``): ``python -m
bench promise --quick``. Any other option is refused: a suite's own options go to its module.
"""

from __future__ import annotations

import importlib
import json
import pkgutil
import platform
import sys
import time
from pathlib import Path

import bench


def main() -> int:
    only = sys.argv[1:]
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
              f"suite's options: python -m bench.bench_<suite> --help)", file=sys.stderr)
        return 2
    rows: list[dict] = []
    for name in suites:
        module = f"bench_{name}"
        if only and name not in only:
            continue
        mod = importlib.import_module(f"bench.{module}")
        t0 = time.perf_counter()
        mine = [f for f in flags if f in getattr(mod, "RUNNER_FLAGS", ())]
        for row in (mod.run(mine) if mine else mod.run()):
            row.setdefault("suite", name)
            rows.append(row)
            print(f"  {row['suite']:<10} {row['name']:<48} {row['value']:>12.4g} {row['unit']:<10}"
                  f" {row.get('target', '')}", flush=True)
        print(f"  ({module} took {time.perf_counter() - t0:.1f} s)", flush=True)
    out = Path(__file__).parent / "results" / "bench.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": platform.platform(), "python": platform.python_version(),
                               "rows": rows}, indent=2))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
