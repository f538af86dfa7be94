"""`host report` on the examples (what `make report` runs): its figures drawn once each.

The model is trained as `make train` trains it (sim_constant + sim_step, dx/dy/dz; not
timed), the report drawn on those two runs and sim_random. In one process, figure by
figure, the report's own PNG step (host.analysis.png.save_png: one draw with the
figure's constrained layout, the clipped-label check on that drawing, the PNG written from
its pixels) is timed against ``Figure.savefig`` of a fresh copy of the same figure (what
drawing it once costs), in alternating order; the PNGs must have the same pixels.
Target: the report's step at most 1.2x savefig's.

Information beside it: the share of the draw that is matplotlib's constrained layout (two
passes over every axes' tick labels and legends before the pixels are drawn; a figure
without it would look different), the whole of build_report against savefig of its figures
once, and `host report` in a fresh process, start to end.
"""

from __future__ import annotations

import io
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.bench_train import timed_process
from bench.goal import INFO, goal

ROOT = Path(__file__).resolve().parents[1]
TRAIN = [ROOT / "examples" / "sim_constant.csv", ROOT / "examples" / "sim_step.csv"]
TEST = ROOT / "examples" / "sim_random.csv"
TARGETS = ("dx_um", "dy_um", "dz_um")
RATIO_TARGET = 1.2


def _train(out: Path) -> Path:
    cmd = [sys.executable, "-m", "thermal_comp.host", "-q", "train", *map(str, TRAIN), "--out",
           str(out)]
    for t in TARGETS:
        cmd += ["--target", t]
    subprocess.run(cmd, check=True, capture_output=True, cwd=ROOT)
    return out / "model.json"


class PairedSave:
    """The report's PNG step (``save``, host.analysis.report's) in place of it, each figure
    timed against savefig of a fresh copy, in alternating order, and their pixels compared.

    ``remember`` wraps each figure function so the copy can be made again from its last
    arguments; ``totals`` holds the seconds of each part, the figures and those that differ.
    """

    def __init__(self, save: Callable, dpi: float) -> None:
        self.save = save
        self.dpi = dpi
        self.again: Callable | None = None
        self.totals: dict = {"report": 0.0, "savefig": 0.0, "layout": 0.0, "copies": 0.0,
                             "figures": 0, "differ": 0}

    def remember(self, make: Callable) -> Callable:
        def wrapped(*args):
            self.again = lambda: make(*args)
            return make(*args)
        return wrapped

    def _time_layout(self, fig) -> None:
        engine = fig.get_layout_engine()
        execute = engine.execute

        def execute_timed(f):
            t0 = time.perf_counter()
            execute(f)
            self.totals["layout"] += time.perf_counter() - t0
        engine.execute = execute_timed

    def __call__(self, fig, path):
        from matplotlib import image

        totals = self.totals
        t0 = time.perf_counter()
        fresh = self.again()[0]
        totals["copies"] += time.perf_counter() - t0
        self._time_layout(fig)
        buf = io.BytesIO()

        def ours():
            t0 = time.perf_counter()
            clipped = self.save(fig, path)
            totals["report"] += time.perf_counter() - t0
            return clipped

        def once():
            t0 = time.perf_counter()
            fresh.savefig(buf, format="png", dpi=self.dpi)
            totals["savefig"] += time.perf_counter() - t0

        if totals["figures"] % 2:
            once()
            clipped = ours()
        else:
            clipped = ours()
            once()
        buf.seek(0)
        a, b = image.imread(path), image.imread(buf)
        totals["differ"] += a.shape != b.shape or not np.array_equal(a, b)
        totals["figures"] += 1
        return clipped


def paired(model: Path, out: Path) -> dict:
    """build_report with each figure's PNG step timed against savefig of a fresh copy."""
    import thermal_comp.host.analysis.report as rep

    save = rep._save
    saver = PairedSave(save, rep.plots.PNG_DPI)
    totals = saver.totals
    figures = dict(rep.FIGURES)
    try:
        rep.FIGURES.update({k: saver.remember(f) for k, f in figures.items()})
        rep._save = saver
        t0 = time.perf_counter()
        rep.build_report(model, [*TRAIN, TEST], out, quiet=True)
        # the report alone: without the copies made and drawn here for the comparison
        totals["build"] = time.perf_counter() - t0 - totals["copies"] - totals["savefig"]
    finally:
        rep.FIGURES.update(figures)
        rep._save = save
    return totals


def run() -> list[dict]:
    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        model = _train(tmpdir / "build")
        t = paired(model, tmpdir / "paired")
        cli = timed_process([sys.executable, "-m", "thermal_comp.host", "-q", "report",
                             str(model), "--runs",
                             *map(str, [*TRAIN, TEST]), "-o", str(tmpdir / "report")],
                            repeat=2)
    n = t["figures"]
    render = t["report"] - t["layout"]
    return [
        {"name": f"host report PNG step / savefig once ({n} figures)",
         "value": t["report"] / t["savefig"], "unit": "x", "target": f"<= {RATIO_TARGET:g}x",
         "goal": goal("<=", RATIO_TARGET),
         "detail": f"{t['report']:.2f} s against {t['savefig']:.2f} s, paired per figure "
                   "in alternating order"},
        {"name": "host report PNGs whose pixels differ from savefig's", "value": t["differ"],
         "unit": f"of {n}", "target": "0", "goal": goal("==", 0)},
        {"name": "host report: constrained layout / rest of the draw",
         "value": t["layout"] / render, "unit": "x", "goal": INFO,
         "detail": f"layout {t['layout']:.2f} s, drawing + check + PNG {render:.2f} s"},
        {"name": "host report (build_report) / savefig of its figures once",
         "value": t["build"] / t["savefig"], "unit": "x", "goal": INFO,
         "detail": f"{t['build']:.2f} s: the PNG step above, building the figures, reading "
                   "the runs, peers, the service day, tables and HTML"},
        {"name": "host report on the examples, fresh process", "value": cli.fastest,
         "unit": "s", "goal": INFO,
         "detail": f"3 runs x 3 axes; {cli.describe()}; peak memory {cli.peak_mb:.0f} MB"},
    ]


if __name__ == "__main__":
    for row in run():
        print(row)
