"""bench.accuracy_figure: the bench's two panels carry the numbers of the cases given."""

from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np
import pytest

from bench import accuracy_figure as fig_mod
from bench import bench_accuracy as acc


def _case(source: str, ours: float, peers: tuple[float, float], promised: float,
          highest: float) -> acc.CaseResult:
    c = acc.CaseResult(source, "g", f"t{ours}", "dz_um", "start")
    c.rmse_um = {"default": ours, "no effects": ours, "paper": ours, "OLS all": peers[0],
                 "lasso+lags": peers[1]}
    c.promised_um = {"default": promised}
    c.highest_fold_um = {"default": highest}
    return c


CASES = [_case("sim_dev", 2.0, (1.0, 4.0), 1.0, 3.0),
         _case("sim_dev", 1.0, (float("nan"), 2.0), 4.0, 5.0),  # a skipped peer is no best
         _case("fl", 3.0, (6.0, 5.0), 1.0, 1.5)]


def test_the_panels_show_the_ratios_their_geometric_means_and_every_promise(tmp_path):
    summary = acc.summarise(CASES)
    figure = fig_mod.draw(CASES, summary)
    left, right = figure.axes
    assert [t.get_text() for t in left.get_xticklabels()] == ["sim_dev", "FL_THERMAL"]
    dots = sorted(float(y) for c in left.collections if not hasattr(c, "get_segments")
                  for _, y in c.get_offsets())
    assert dots == pytest.approx([0.5, 0.6, 2.0])  # 2/1, 1/2 (NaN peer skipped), 3/5
    bars = sorted(float(seg[0][1]) for c in left.collections if hasattr(c, "get_segments")
                  for seg in c.get_segments())
    assert bars == pytest.approx([0.6, 1.0])  # fl 0.6; sim_dev sqrt(2 * 0.5)
    points = np.vstack([c.get_offsets() for c in right.collections
                        if c.get_label().startswith(("sim_dev", "FL"))])
    assert sorted(map(tuple, points)) == [(1.0, 2.0), (1.0, 3.0), (4.0, 1.0)]
    labels = [t.get_text() for t in right.get_legend().get_texts()]
    # test / promised 2 (inside), 0.25 and 3 (outside)
    assert "sim_dev: 1 of 2 within 2×" in labels and "FL_THERMAL: 0 of 1 within 2×" in labels
    results = tmp_path / "accuracy.json"
    results.write_text(json.dumps({"cases": [asdict(c) for c in CASES], "summary": summary}))
    out = fig_mod.save(results, tmp_path / "accuracy.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
