"""bench.accuracy_figure: the bench's two panels carry the numbers of the cases given."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bench import accuracy_figure as fig_mod

PEERS = ["OLS all", "lasso+lags"]


def _case(source: str, ours: float, peers: tuple[float, float], promised: float,
          highest: float) -> dict:
    return {"source": source, "rmse_um": {"default": ours, "OLS all": peers[0],
                                          "lasso+lags": peers[1]},
            "promised_um": {"default": promised}, "highest_fold_um": {"default": highest}}


CASES = [_case("sim_dev", 2.0, (1.0, 4.0), 1.0, 3.0),
         _case("sim_dev", 1.0, (float("nan"), 2.0), 4.0, 5.0),  # a skipped peer is no best
         _case("fl", 3.0, (6.0, 5.0), 1.0, 1.5)]


def test_best_peer_and_ratios_skip_what_a_peer_did_not_fit():
    assert fig_mod.best_peer_um(CASES[1], PEERS) == 2.0
    assert math.isnan(fig_mod.best_peer_um({"rmse_um": {"OLS all": float("nan")}}, PEERS))
    ratios = fig_mod.ratios_by_source(CASES, PEERS)
    assert list(ratios) == ["sim_dev", "fl"]  # no sim case: no column for it
    np.testing.assert_allclose(ratios["sim_dev"], [2.0, 0.5])
    np.testing.assert_allclose(ratios["fl"], [0.6])


def test_the_panels_show_the_geometric_means_and_every_promise(tmp_path):
    figure = fig_mod.draw(CASES, PEERS)
    left, right = figure.axes
    bars = sorted(float(seg[0][1]) for c in left.collections if hasattr(c, "get_segments")
                  for seg in c.get_segments())
    assert bars == pytest.approx([0.6, 1.0])  # fl 0.6; sim_dev sqrt(2 * 0.5)
    points = np.vstack([c.get_offsets() for c in right.collections
                        if c.get_offsets().size and c.get_label().startswith(("sim_dev", "FL"))])
    assert sorted(map(tuple, points)) == [(1.0, 2.0), (1.0, 3.0), (4.0, 1.0)]
    labels = [t.get_text() for t in right.get_legend().get_texts()]
    assert "sim_dev: 1 of 2 within 2×" in labels and "FL_THERMAL: 0 of 1 within 2×" in labels
    results = tmp_path / "accuracy.json"
    results.write_text(json.dumps({"cases": CASES, "columns": {"peers": PEERS}}))
    out = fig_mod.save(results, tmp_path / "accuracy.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
