"""Run every bench/bench_*.py, print one table and write bench/results/bench.json.

Each module defines ``run() -> list[dict]``; a row has at least ``name``, ``value``, ``unit``
and optionally ``target`` (a human-readable goal such as "< 10 s") and ``detail``.
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
    rows: list[dict] = []
    for info in sorted(pkgutil.iter_modules(bench.__path__), key=lambda m: m.name):
        if not info.name.startswith("bench_"):
            continue
        if only and info.name.removeprefix("bench_") not in only:
            continue
        mod = importlib.import_module(f"bench.{info.name}")
        t0 = time.perf_counter()
        for row in mod.run():
            row.setdefault("suite", info.name.removeprefix("bench_"))
            rows.append(row)
            print(f"  {row['suite']:<10} {row['name']:<48} {row['value']:>12.4g} {row['unit']:<10}"
                  f" {row.get('target', '')}", flush=True)
        print(f"  ({info.name} took {time.perf_counter() - t0:.1f} s)", flush=True)
    out = Path(__file__).parent / "results" / "bench.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": platform.platform(), "python": platform.python_version(),
                               "rows": rows}, indent=2))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
