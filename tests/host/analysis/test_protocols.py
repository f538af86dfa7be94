"""compare-protocols: the train x test matrix on simulated and on given runs."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from thermal_comp.host.analysis import (
    PRODUCTION,
    ProtocolComparisonError,
    combine,
    compare_protocols,
    parse_runs,
    simulate_runs,
    write_outputs,
)
from thermal_comp.host.cli import main
from thermal_comp.host.io import load_run

AXES = ["dx_um", "dz_um"]


@pytest.fixture(scope="module")
def sim_runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    return simulate_runs(out, ["constant", "step"], hours=3.0, cool_hours=2.0, dt_s=120.0,
                         n_sensors=8, seed=3)


@pytest.fixture(scope="module")
def comparison(sim_runs):
    return compare_protocols(sim_runs, AXES, max_sensors=3, groups=4)


def test_simulated_runs_are_one_machine_on_different_days(sim_runs):
    assert list(sim_runs) == ["constant", "step", PRODUCTION]
    assert [len(v) for v in sim_runs.values()] == [2, 2, 1]
    a, b = (load_run(p, AXES) for p in sim_runs["constant"])
    assert a.sensor_names == b.sensor_names
    assert not np.array_equal(a.temperatures, b.temperatures)  # another day: other noise
    truth = json.loads(open(sim_runs[PRODUCTION][0].replace(".csv", ".truth.json")).read())
    assert truth["program"]["protocol"] == "random"


def test_each_cell_is_the_rmse_of_that_model_on_that_run(comparison, sim_runs):
    assert comparison.train == ["constant", "step"]
    assert comparison.test == ["constant", "step", PRODUCTION]
    assert not comparison.in_sample.any()  # every protocol has a second day to test on
    # recompute one off-diagonal and one diagonal cell by hand from the stored terms
    from thermal_comp.host.train import train_model

    model = train_model([sim_runs["constant"][0]], AXES, max_sensors=3, groups=4,
                        effects=False, fit="ols", nested=False)
    for col, path in ((1, sim_runs["step"][1]), (0, sim_runs["constant"][1])):
        run = load_run(path, AXES)
        for k, axis in enumerate(AXES):
            ax = model["axes"][axis]
            pred = ax["intercept"] + sum(t["coef"] * run.column(t["source"])
                                         for t in ax["terms"])  # static terms: coef * T
            k_ref = model["reference"]["samples"]  # both referenced at the run's start
            y = run.displacements[:, k]
            y, pred = (v - np.array([v[:min(i, k_ref - 1) + 1].mean() for i in range(v.size)])
                       for v in (y, pred))
            err = float(np.sqrt(np.mean((y - pred) ** 2)))
            assert comparison.rmse_um[axis][0, col] == pytest.approx(err, rel=1e-9)


def test_outputs_hold_the_same_numbers(comparison, tmp_path):
    csv_path, json_path = write_outputs(comparison, tmp_path)
    rows = list(csv.DictReader(csv_path.open()))
    assert len(rows) == 2 * 3 * len(AXES)
    cell = next(r for r in rows if r["train"] == "step" and r["test"] == PRODUCTION
                and r["axis"] == "dz_um")
    assert float(cell["rmse_um"]) == pytest.approx(comparison.rmse_um["dz_um"][1, 2], abs=1e-4)
    doc = json.loads(json_path.read_text())
    assert doc["rmse_um"]["dx_um"][0][1] == pytest.approx(comparison.rmse_um["dx_um"][0, 1],
                                                          abs=1e-4)
    mean = np.mean([comparison.rmse_um[a] for a in AXES], axis=0)
    assert doc["mean_rmse_um"][1][0] == pytest.approx(mean[1, 0], abs=1e-4)
    assert doc["matrix"] == doc["mean_rmse_um"]  # what host report reads
    assert [r["train"] for r in doc["ranking"]] == sorted(
        ["constant", "step"], key=lambda n: np.mean(mean[comparison.train.index(n)][
            [j for j, t in enumerate(comparison.test) if t != n]]))


def test_combine_averages_repeats(comparison):
    other = combine([comparison])
    assert other is comparison
    twice = combine([comparison, comparison])
    np.testing.assert_allclose(twice.rmse_um["dz_um"], comparison.rmse_um["dz_um"])
    assert twice.settings["repeats"] == 2


def test_given_runs_with_one_run_per_protocol_are_marked_in_sample(sim_runs, tmp_path, capsys):
    args = ["compare-protocols", "--runs", f"constant={sim_runs['constant'][0]}",
            f"step={sim_runs['step'][0]}", "--target", "dz_um", "--max-sensors", "2",
            "--groups", "3", "--json"]
    assert main(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["in_sample"] == [[True, False], [False, True]]
    assert doc["train"] == ["constant", "step"] and doc["targets"] == ["dz_um"]


def test_bad_runs_are_refused(tmp_path):
    with pytest.raises(ProtocolComparisonError, match="NAME=RUN.csv"):
        parse_runs(["constant.csv", "step=b.csv"])
    with pytest.raises(ProtocolComparisonError, match="at least two"):
        parse_runs(["constant=a.csv"])
    assert parse_runs(["a=1.csv", "b=2.csv", "a=3.csv"]) == {"a": ["1.csv", "3.csv"],
                                                              "b": ["2.csv"]}
    with pytest.raises(ProtocolComparisonError, match="unknown protocol"):
        simulate_runs(tmp_path, ["constant", "ramp"])


def _two_protocols(a_score: float, b_score: float):
    """A hand-made comparison whose ranking scores are a_score (a) and b_score (b): each
    protocol's score is its RMSE on the other protocol's run, the off-diagonal cell."""
    from thermal_comp.host.analysis.protocol_matrix import Comparison

    m = np.array([[0.1, a_score], [b_score, 0.1]])
    return Comparison(["a", "b"], ["a", "b"], ["x"], {"x": m}, np.zeros((2, 2), bool),
                      {"a": [], "b": []}, raw_rms_um={"a": {"x": 5.0}, "b": {"x": 5.0}})


def test_a_winner_only_when_the_gap_exceeds_the_spread_over_repeats():
    clear = combine([_two_protocols(a, b) for a, b in ((1.0, 2.0), (1.1, 2.1), (0.9, 1.9))])
    v = clear.verdict()
    assert v["winner"] == "a" and v["repeats"] == 3
    assert v["gap_um"] == pytest.approx(1.0)
    assert v["spread_um"]["a"] == pytest.approx(np.std([1.0, 1.1, 0.9], ddof=1), abs=1e-4)

    # means 1.0 vs 1.2, but each repeat scatters by about 0.4-0.5: no winner
    noisy = combine([_two_protocols(a, b) for a, b in ((1.0, 1.2), (1.5, 0.8), (0.5, 1.6))])
    v = noisy.verdict()
    assert v["winner"] is None and v["best"] == "a"
    assert v["spread_used_um"] == pytest.approx(np.std([1.0, 1.5, 0.5], ddof=1), abs=1e-4)
    assert "within the spread" in v["reason"]

    single = _two_protocols(0.33, 0.34).verdict()  # one repeat: no spread, no winner
    assert single["winner"] is None and "one repeat" in single["reason"]


def test_cli_repeats_by_default(monkeypatch, capsys):
    import thermal_comp.host.commands.compare_protocols as cmd

    seen = []

    def fake_sim(out_dir, protocols, **kw):
        seen.append(kw["seed"])
        return {}

    monkeypatch.setattr(cmd, "simulate_runs", fake_sim)
    monkeypatch.setattr(cmd, "compare_protocols", lambda runs, targets, **kw: _two_protocols(
        1.0 + len(seen) / 100, 2.0))
    assert main(["compare-protocols", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert seen == [0, 1000, 2000]  # three sets of days
    assert doc["verdict"]["repeats"] == 3 and doc["verdict"]["winner"] == "a"
