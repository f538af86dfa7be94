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

RESULTS_DIR = Path(__file__).resolve().parent / "results"
SOURCES = {"sim": "project simulator", "sim_dev": "sim_dev", "fl": "FL_THERMAL"}
COLOURS = {"sim": "tab:blue", "sim_dev": "tab:orange", "fl": "tab:green"}
TARGET = 0.8  # issue 13: geometric mean of ours / best peer on sim_dev and FL


def best_peer_um(case: dict, peers: Sequence[str]) -> float:
    """The lowest finite test RMSE of the peers on this case (NaN when every peer skipped)."""
    values = [case["rmse_um"][p] for p in peers
              if p in case["rmse_um"] and math.isfinite(case["rmse_um"][p])]
    return min(values) if values else math.nan


def ratios_by_source(cases: Sequence[dict], peers: Sequence[str]) -> dict[str, np.ndarray]:
    """Ours (default) / best peer for every case with both, per source, in SOURCES order."""
    out: dict[str, list[float]] = {s: [] for s in SOURCES}
    for c in cases:
        best = best_peer_um(c, peers)
        if c["source"] in out and best > 0 and math.isfinite(c["rmse_um"].get("default", math.nan)):
            out[c["source"]].append(c["rmse_um"]["default"] / best)
    return {s: np.asarray(v) for s, v in out.items() if v}


def draw(cases: Sequence[dict], peers: Sequence[str]) -> Figure:
    """The two panels for the cases of accuracy.json (``peers``: its peer columns)."""
    fig = Figure(figsize=(12.0, 5.2), layout="constrained")
    left, right = fig.subplots(1, 2, width_ratios=[1, 1.25])
    rng = np.random.default_rng(0)  # horizontal jitter only: the values are not touched
    for k, (source, r) in enumerate(ratios_by_source(cases, peers).items()):
        x = k + rng.uniform(-0.18, 0.18, r.size)
        left.scatter(x, r, s=14, alpha=0.6, color=COLOURS[source])
        geo = float(np.exp(np.mean(np.log(r))))
        left.hlines(geo, k - 0.3, k + 0.3, color="black", lw=2.5)
        left.annotate(f"{geo:.3f}", (k + 0.32, geo), va="center", fontsize=9)
    names = [SOURCES[s] for s in ratios_by_source(cases, peers)]
    left.set_xticks(range(len(names)), names)
    left.set_xlim(-0.6, len(names) - 0.1)  # room for the means' labels, whatever the count
    left.set_yscale("log")
    left.axhline(1.0, color="grey", lw=0.8)
    left.axhline(TARGET, color="black", lw=1.0, ls="--", label=f"target {TARGET} (geometric mean)")
    left.set_ylabel("ours / best of the ten peers, per case")
    left.set_title("Unseen runs: ours against the best peer picked after the test")
    left.legend(fontsize=8, loc="upper left")

    lo, hi = math.inf, 0.0
    for source in SOURCES:
        rows = [c for c in cases if c["source"] == source
                and c.get("promised_um", {}).get("default", 0) > 0]
        if not rows:
            continue
        promised = np.array([c["promised_um"]["default"] for c in rows])
        test = np.array([c["rmse_um"]["default"] for c in rows])
        top = np.array([c.get("highest_fold_um", {}).get("default", math.nan) for c in rows])
        inside = int(np.sum((test >= promised / 2) & (test <= 2 * promised)))
        right.scatter(promised, test, s=16, alpha=0.7, color=COLOURS[source],
                      label=f"{SOURCES[source]}: {inside} of {len(rows)} within 2×")
        spread = np.isfinite(top)
        right.hlines(test[spread], promised[spread], top[spread], color=COLOURS[source],
                     lw=0.6, alpha=0.35)
        values = np.concatenate([promised, test, top[spread]])
        lo, hi = min(lo, float(values.min())), max(hi, float(values.max()))
    if hi > 0:
        grid = np.array([lo / 2, hi * 2])
        right.fill_between(grid, grid / 2, grid * 2, color="grey", alpha=0.15, lw=0,
                           label="within a factor 2")
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
    draw(doc["cases"], doc["columns"]["peers"]).savefig(out, dpi=110)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, default=RESULTS_DIR / "accuracy.json")
    ap.add_argument("--out", type=Path, default=RESULTS_DIR / "accuracy.png")
    args = ap.parse_args(argv)
    if not args.results.exists():
        ap.error(f"{args.results}: no bench results yet (run `python -m bench accuracy`)")
    print(f"wrote {save(args.results, args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
