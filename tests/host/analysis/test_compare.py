"""`host compare`: every peer is present, and the peers' numbers are recomputed with numpy."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest

from thermal_comp.host.analysis import MethodResult, best_methods, best_subset, compare_methods
from thermal_comp.host.cli import main
from thermal_comp.host.io import Run, write_run


def _run(path: str, n: int, seed: int, scale: float) -> Run:
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    a = np.sin(2 * np.pi * t / 150.0) * scale
    b = np.cos(2 * np.pi * t / 390.0) * scale
    T = np.column_stack([a + 0.05 * rng.normal(size=n), a * 0.8 + 0.3 * rng.normal(size=n),
                         b + 0.05 * rng.normal(size=n), rng.normal(size=n),
                         a + b + 0.2 * rng.normal(size=n), 0.5 * b + 0.3 * rng.normal(size=n)])
    y = 2.0 * a - 1.0 * b + 0.05 * rng.normal(size=n)
    return Run(path, t * 60.0, [f"T{i}" for i in range(1, 7)], T + 22.0, ["dz_um"], y[:, None])


def _ols_test_rmse(train: Run, test: Run, cols: list[int]) -> float:
    A = np.column_stack([np.ones(train.n_samples), train.temperatures[:, cols]])
    beta, *_ = np.linalg.lstsq(A, train.target("dz_um"), rcond=None)
    At = np.column_stack([np.ones(test.n_samples), test.temperatures[:, cols]])
    return float(np.sqrt(np.mean((test.target("dz_um") - At @ beta) ** 2)))


@pytest.fixture(scope="module")
def doc():
    train = [_run("a.csv", 400, 1, 1.0), _run("b.csv", 400, 2, 1.3)]
    test = [_run("c.csv", 300, 3, 1.6)]
    return train, test, compare_methods(train, test, ["dz_um"], engineering=["T2", "T6"],
                                        groups=4, reference="none")


def test_all_methods_reported(doc):
    _, _, d = doc
    names = [m["method"] for m in d["axes"]["dz_um"]["methods"]]
    for key in ("ours, validated", "ours, paper 000", "OLS, all sensors", "4 most correlated",
                "engineering pick", "SequentialFeatureSelector", "LassoCV", "exhaustive"):
        assert any(n.startswith(key) for n in names), key
    for m in d["axes"]["dz_um"]["methods"]:
        assert m["n_sensors"] == len(m["sensors"]) and m["fit_time_s"] >= 0


def test_peer_numbers_match_numpy(doc):
    train, test, d = doc
    rows = {m["method"].split(" (")[0].split(",")[0]: m for m in d["axes"]["dz_um"]["methods"]}
    merged = Run("ab", np.r_[train[0].time_s, train[1].time_s],
                 train[0].sensor_names, np.vstack([r.temperatures for r in train]), ["dz_um"],
                 np.vstack([r.displacements for r in train]))
    assert rows["OLS"]["test_rmse_um"] == pytest.approx(
        _ols_test_rmse(merged, test[0], list(range(6))), rel=1e-9)
    assert rows["engineering pick"]["test_rmse_um"] == pytest.approx(
        _ols_test_rmse(merged, test[0], [1, 5]), rel=1e-9)
    y = merged.target("dz_um")
    r = [abs(np.corrcoef(merged.temperatures[:, j], y)[0, 1]) for j in range(6)]
    top = sorted(np.argsort(r)[::-1][:4])
    corr_row = next(m for m in d["axes"]["dz_um"]["methods"] if "most correlated" in m["method"])
    assert sorted(corr_row["sensors"]) == [f"T{j + 1}" for j in top]
    assert d["axes"]["dz_um"]["raw_rms_um"] == pytest.approx(
        np.sqrt(np.mean(test[0].target("dz_um") ** 2)))


def test_best_subset_is_the_brute_force_minimum():
    rng = np.random.default_rng(5)
    X = rng.normal(size=(200, 6)).cumsum(axis=0)
    y = X[:, 1] - 2 * X[:, 4] + rng.normal(size=200)
    errs = {}
    for combo in itertools.combinations(range(6), 2):
        A = np.column_stack([np.ones(200), X[:, combo]])
        beta, *_ = np.linalg.lstsq(A, y, rcond=None)
        errs[combo] = float(np.sum((y - A @ beta) ** 2))
    assert tuple(best_subset(X, y, 2)) == min(errs, key=errs.get)


def test_exhaustive_search_skipped_above_limit():
    train = [_run("a.csv", 300, 1, 1.0)]
    test = [_run("c.csv", 200, 3, 1.2)]
    d = compare_methods(train, test, ["dz_um"], groups=4, exhaustive_limit=1)
    row = next(m for m in d["axes"]["dz_um"]["methods"] if m["method"].startswith("exhaustive"))
    assert row["note"].startswith("skipped") and math.isnan(row["test_rmse_um"])


def test_cli_compare_json_with_split(tmp_path, capsys):
    run = _run("x.csv", 600, 7, 1.0)
    path = tmp_path / "x.csv"
    cols = {n: run.temperatures[:, i] for i, n in enumerate(run.sensor_names)}
    cols["dz_um"] = run.target("dz_um")
    write_run(path, run.time_s, cols)
    split_h = run.time_s[400] / 3600
    assert main(["compare", str(path), "--split-at-h", str(split_h), "--target", "dz_um",
                 "--groups", "4", "--engineering", "T1,T3", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["test"][0].endswith("h]") and "dz_um" in d["axes"]
    rows = d["axes"]["dz_um"]["methods"]
    assert all(set(m) >= {"method", "n_sensors", "test_rmse_um", "fit_time_s"} for m in rows)
    assert main(["compare", str(path), "--target", "dz_um"]) == 2
    assert "give test runs with --test" in capsys.readouterr().err
    assert main(["compare", str(path), "--split-at-h", str(split_h), "--target", "dz_um",
                 "--engineering", "T9"]) == 2
    assert "unknown sensor(s) T9" in capsys.readouterr().err


def test_best_overall_and_best_the_box_can_read():
    rows = [MethodResult("ours", ["T1", "T2"], 2.0, 3.0, 0.1),
            MethodResult("all sixteen", [f"T{i}" for i in range(16)], 1.5, 2.0, 0.1),
            MethodResult("skipped", [], math.nan, math.nan, 0.0, "skipped"),
            MethodResult("eight", [f"T{i}" for i in range(8)], 1.9, 2.5, 0.1)]
    best = best_methods(rows)
    assert best["best"] == {"method": "all sixteen", "test_rmse_um": 1.5}
    assert best["best_within_box"] == {"method": "eight", "test_rmse_um": 1.9}  # 8 fits
    assert best_methods(rows[2:3]) == {"best": None, "best_within_box": None}


def test_compare_reports_the_best_method_of_each_axis(doc):
    _, _, d = doc
    axis = d["axes"]["dz_um"]
    scored = [m for m in axis["methods"] if not math.isnan(m["test_rmse_um"])]
    lowest = min(scored, key=lambda m: m["test_rmse_um"])
    assert axis["best"] == {"method": lowest["method"], "test_rmse_um": lowest["test_rmse_um"]}


def _lagged_run(path: str, seed: int, hours: float = 10.0) -> Run:
    """Two heat sources; the drift follows the first one through a 30-min lag (a part no
    thermocouple sees), which no static model of the temperatures has."""
    rng = np.random.default_rng(seed)
    n = int(hours * 60)
    t = np.arange(n) * 60.0
    power = np.repeat(rng.uniform(0, 1, size=n // 30 + 1), 30)[:n]  # 30-min steps
    a = 1 - np.exp(-60.0 / 600.0)
    src = np.zeros(n)
    for i in range(1, n):
        src[i] = src[i - 1] + a * (5 * power[i] - src[i - 1])
    b = 1 - np.exp(-60.0 / 1800.0)
    hidden = np.zeros(n)
    for i in range(1, n):
        hidden[i] = hidden[i - 1] + b * (src[i] - hidden[i - 1])
    T = np.column_stack([src, 0.5 * src + rng.normal(0, 0.3, n).cumsum() * 0.02,
                         rng.normal(0, 0.3, n).cumsum() * 0.02, 0.3 * src]) + 20.0
    T += rng.normal(0, 0.02, T.shape)
    y = 4.0 * hidden + 0.05 * rng.normal(size=n)
    return Run(path, t, [f"T{i}" for i in range(1, 5)], T, ["dz_um"], y[:, None])


def test_the_box_model_is_compared_and_catches_what_static_fits_miss():
    train = [_lagged_run("a.csv", 11), _lagged_run("b.csv", 12)]
    test = [_lagged_run("c.csv", 13)]
    d = compare_methods(train, test, ["dz_um"], groups=3, reference="start")
    rows = {m["method"]: m for m in d["axes"]["dz_um"]["methods"]}
    box = rows["ours, as host train fits it (the box's model)"]
    static = rows["ours, validated selection + OLS"]
    assert 0 < box["n_sensors"] <= 8 and box["note"].startswith("fit ridge")
    # the lag of the first sensor is in the box's basis, not in any static fit
    assert box["test_rmse_um"] < 0.7 * static["test_rmse_um"]
    assert box["test_rmse_um"] < rows["OLS, all sensors"]["test_rmse_um"]
    # the selection bench compares selections alone
    bare = compare_methods(train, test, ["dz_um"], groups=3, reference="start", box_model=False)
    assert all(not m["method"].startswith("ours, as host train")
               for m in bare["axes"]["dz_um"]["methods"])


def test_compare_fits_the_box_model_of_a_bending_axis_as_host_train_would():
    from thermal_comp.host.analysis.evaluate import predict
    from thermal_comp.host.fitting import Reference
    from thermal_comp.host.train import train_model

    train = [_lagged_run("a.csv", 11), _lagged_run("b.csv", 12)]
    test = [_lagged_run("c.csv", 13)]
    bent = compare_methods(train, test, ["dz_um"], groups=3, reference="start",
                           bending=["dz_um"], methods=("paper",))
    model = train_model(train, ["dz_um"], groups=3, reference="start", nested=False,
                        bending=["dz_um"])
    ref = Reference.of_kind("start")
    err = np.concatenate([ref.apply(t.target("dz_um")) - predict(model, t)["dz_um"]
                          for t in test])
    plain = compare_methods(train, test, ["dz_um"], groups=3, reference="start",
                            methods=("paper",))["axes"]["dz_um"]["methods"][0]
    box = bent["axes"]["dz_um"]["methods"][0]
    assert box["method"].startswith("ours, as host train")
    assert box["test_rmse_um"] != pytest.approx(plain["test_rmse_um"], rel=1e-6)
    assert box["test_rmse_um"] == pytest.approx(float(np.sqrt(np.mean(err ** 2))), rel=1e-9)
    with pytest.raises(Exception, match="--bending dx_um: not among the targets"):
        compare_methods(train, test, ["dz_um"], bending=["dx_um"])


def test_paper_002_peer_takes_the_largest_absolute_correlations_ties_in_column_order():
    """most_correlated (host compare's and the report's peer) against numpy's corrcoef."""
    from thermal_comp.host.analysis.compare import most_correlated

    rng = np.random.default_rng(3)
    y = rng.normal(size=400)
    strong = -3 * y + 0.1 * rng.normal(size=400)
    # column 2 is constant (r = 0); column 4 repeats column 1, a tie: the earlier column first
    X = np.column_stack([0.2 * y + rng.normal(size=400), strong, np.ones(400),
                         y + rng.normal(size=400), strong])
    r = [abs(np.corrcoef(X[:, j], y)[0, 1]) if np.std(X[:, j]) > 0 else 0.0 for j in range(5)]
    expected = sorted(range(5), key=lambda j: (-round(r[j], 12), j))[:3]
    assert most_correlated(X, y, 3).tolist() == expected == [1, 4, 3]
