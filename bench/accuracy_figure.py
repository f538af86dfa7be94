"""The accuracy bench at a glance: ours / the best peer per case, and the promise against the
unseen run (bench/results/accuracy.png, drawn from bench/results/accuracy.json).

Left: every case's ours (default) / best peer per source on a log scale, the geometric mean
as a bar, issue 13's target (0.8) dashed. Right: the test RMSE against the error ``host
train`` promised (its lowest nested fold), log-log, the band of a factor 2 shaded, and each
case's spread up to its highest fold as a thin line.

    python -m bench.accuracy_figure          # redraw from the last bench/results/accuracy.json
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from bench.accuracy_cases import CALIBRATION_FACTOR, RESULTS, CaseResult  # noqa: E402

SOURCES = {"sim": "project simulator", "sim_dev": "sim_dev", "fl": "FL_THERMAL",
           "fl_next": "FL, next cycle", "sim_other": "simulator, other machines"}
COLOURS = {"sim": "tab:blue", "sim_dev": "tab:orange", "fl": "tab:green",
           "fl_next": "tab:red", "sim_other": "tab:purple"}
TARGET = 0.8  # issue 13: geometric mean of ours / best peer on sim_dev and FL


def draw(cases: Sequence[CaseResult], summary: dict) -> Figure:
    """The two panels for the bench's cases and its summary (accuracy_summary.summarise: the
    geometric means and the calibration counts are its numbers, not recomputed here)."""
    fig = Figure(figsize=(12.0, 5.2), layout="constrained")
    left, right = fig.subplots(1, 2, width_ratios=[1, 1.25])
    sources = [s for s in SOURCES if s in summary["per_source"]]
    rng = np.random.default_rng(0)  # horizontal jitter only: the values are not touched
    for k, source in enumerate(sources):
        r = np.array([c.ratio() for c in cases if c.source == source])
        r = r[np.isfinite(r) & (r > 0)]
        left.scatter(k + rng.uniform(-0.18, 0.18, r.size), r, s=14, alpha=0.6,
                     color=COLOURS[source])
        geo = summary["per_source"][source]["geomean default / best peer"]
        left.hlines(geo, k - 0.3, k + 0.3, color="black", lw=2.5)
        left.annotate(f"{geo:.3f}", (k + 0.32, geo), va="center", fontsize=9)
    # two lines per tick: five sources' names side by side would run into each other
    left.set_xticks(range(len(sources)), [SOURCES[s].replace(" ", "\n", 1)
                                          for s in sources], fontsize=9)
    left.set_xlim(-0.6, len(sources) - 0.1)  # room for the means' labels, whatever the count
    left.set_yscale("log")
    left.axhline(1.0, color="grey", lw=0.8)
    left.axhline(TARGET, color="black", lw=1.0, ls="--", label=f"target {TARGET} (geometric mean)")
    left.set_ylabel("ours / best of the ten peers, per case")
    left.set_title("Unseen runs: ours against the best peer picked after the test")
    left.legend(fontsize=8, loc="upper left")

    lo, hi = math.inf, 0.0
    for source in sources:
        rows = [c for c in cases if c.source == source and c.promised_um.get("default", 0) > 0]
        if not rows:
            continue
        promised = np.array([c.promised_um["default"] for c in rows])
        test = np.array([c.rmse_um["default"] for c in rows])
        top = np.array([c.highest_fold_um.get("default", math.nan) for c in rows])
        cal = summary["calibration"][source]
        right.scatter(promised, test, s=16, alpha=0.7, color=COLOURS[source],
                      label=f"{SOURCES[source]}: {cal['within factor 2']} of {cal['cases']} "
                      f"within {CALIBRATION_FACTOR:g}×")
        spread = np.isfinite(top)
        right.hlines(test[spread], promised[spread], top[spread], color=COLOURS[source],
                     lw=0.6, alpha=0.35)
        values = np.concatenate([promised, test, top[spread]])
        lo, hi = min(lo, float(values.min())), max(hi, float(values.max()))
    if hi > 0:
        grid = np.array([lo / 2, hi * 2])
        right.fill_between(grid, grid / CALIBRATION_FACTOR, grid * CALIBRATION_FACTOR,
                           color="grey", alpha=0.15, lw=0,
                           label=f"within a factor {CALIBRATION_FACTOR:g}")
        right.plot(grid, grid, color="black", lw=0.8)
        right.set_xlim(grid)
        right.set_ylim(grid)
    right.set_xscale("log")
    right.set_yscale("log")
    right.set_xlabel("promised by host train (µm RMS; line: up to the highest nested fold)")
    right.set_ylabel("test RMSE on the unseen run (µm)")
    right.set_title("The promise against what the unseen run gave")
    right.legend(fontsize=8, loc="upper left")
    return fig


def save(results: Path, out: Path) -> Path:
    """Draw the figure of an accuracy.json and write it as PNG."""
    doc = json.loads(results.read_text())
    draw([CaseResult(**d) for d in doc["cases"]], doc["summary"]).savefig(out, dpi=110)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, default=RESULTS)
    ap.add_argument("--out", type=Path, default=RESULTS.with_suffix(".png"))
    args = ap.parse_args(argv)
    if not args.results.exists():
        ap.error(f"{args.results}: no bench results yet (run `python -m bench accuracy`)")
    print(f"wrote {save(args.results, args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
