"""The accuracy bench's harness (bench/bench_accuracy.py): its start reference against a
hand-computed example, its scoring, a peer's test error against a direct numpy fit on a tiny
case, a peer's out-of-fold error against a direct refit without each fold, and its summary
(geometric mean, the peer picked by validation, the strongest single peer, the loop's check,
the calibration count)."""

import math
from pathlib import Path

import numpy as np
import pytest

from bench import bench_accuracy as acc
from thermal_comp.host.io import write_run


def test_reference_is_the_running_mean_of_the_first_k_samples():
    x = np.array([1.0, 3.0, 5.0, 7.0, 11.0])
    # k = 2: references 1, (1+3)/2, then frozen at 2
    np.testing.assert_allclose(acc.referenced(x, 2), [0.0, 1.0, 3.0, 5.0, 9.0])
    np.testing.assert_allclose(acc.referenced(x, 1), x - 1.0)
    # k beyond the run: every sample is referenced to the mean so far
    np.testing.assert_allclose(acc.referenced(x[:2], 5), [0.0, 1.0])
    cols = np.column_stack([x, 2 * x])
    np.testing.assert_allclose(acc.referenced(cols, 2)[:, 1], 2 * acc.referenced(x, 2))
    # the window is the project's (the box's ZERO window), the same at every period
    from thermal_comp.host.fitting.reference import Reference

    for period in (15.0, 60.0):
        assert acc.reference_window(period) == Reference.of_kind("start").samples
        np.testing.assert_allclose(acc.referenced(cols, 3), Reference("start", 3).apply(cols))


def test_score_start_ignores_a_constant_offset_none_does_not():
    rng = np.random.default_rng(1)
    y = np.cumsum(rng.normal(size=50))
    assert acc.score(y, y + 7.0, "start", 60.0) == pytest.approx(0.0, abs=1e-12)
    assert acc.score(y, y + 7.0, "none", 60.0) == pytest.approx(7.0)
    pred = y + rng.normal(size=50)
    k = acc.reference_window(60.0)
    direct = np.sqrt(np.mean(((pred - pred[:k].mean()) - (y - y[:k].mean()))[k:] ** 2))
    # after the first k samples the reference is the plain mean of the first k
    full = acc.score(y, pred, "start", 60.0)
    head = acc.referenced(pred, k)[:k] - acc.referenced(y, k)[:k]
    assert full == pytest.approx(np.sqrt((np.sum(head ** 2) + direct ** 2 * (50 - k)) / 50))


def _tiny_run(path: Path, seed: int, offset_c: float, n: int = 240) -> None:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 60.0
    heat = 1 - np.exp(-t / 3000.0)
    cols = {f"T{i:02d}": 20 + offset_c + (2 + i) * heat + 0.2 * np.sin(t / (900 + 300 * i))
            + 0.02 * rng.normal(size=n) for i in range(1, 6)}
    cols["spindle_rpm"] = np.full(n, 4000.0)
    dz = 3 * (cols["T01"] - cols["T01"][0]) - 0.5 * (cols["T04"] - cols["T04"][0])
    cols["dy_um"] = 0.5 * (cols["T02"] - cols["T02"][0]) + 0.05 * rng.normal(size=n)
    cols["dz_um"] = dz + 0.05 * rng.normal(size=n)
    write_run(path, t, cols)


def test_peer_test_rmse_equals_a_direct_numpy_fit(tmp_path):
    for i, off in enumerate((0.0, 1.0, 3.0)):  # the test day starts 3 K warmer
        _tiny_run(tmp_path / f"r{i}.csv", i, off)
    job = acc.Job("sim_dev", "tiny", (acc.RunSpec(str(tmp_path / "r0.csv")),
                                      acc.RunSpec(str(tmp_path / "r1.csv"))),
                  (acc.RunSpec(str(tmp_path / "r2.csv")),), ("dz_um",), "start")
    rows, timings = acc.run_job(job)
    (row,) = rows
    assert set(row["rmse_um"]) == set(acc.OURS) | set(acc.PEERS)
    assert set(row["peer_validation_um"]) == set(acc.PEERS)
    assert timings["job"] > 0

    k = acc.reference_window(60.0)

    def load(name):
        data = np.genfromtxt(tmp_path / name, delimiter=",", names=True)
        T = np.column_stack([data[f"T{i:02d}"] for i in range(1, 6)])
        return acc.referenced(T, k), acc.referenced(data["dz_um"], k), data["dz_um"]

    (X0, y0, _), (X1, y1, _), (Xt, _, yt) = load("r0.csv"), load("r1.csv"), load("r2.csv")
    A = np.column_stack([np.vstack([X0, X1]), np.ones(2 * len(y0))])
    coef, *_ = np.linalg.lstsq(A, np.concatenate([y0, y1]), rcond=None)
    pred = np.column_stack([Xt, np.ones(len(yt))]) @ coef
    direct = np.sqrt(np.mean((acc.referenced(pred, k) - acc.referenced(yt, k)) ** 2))
    assert row["rmse_um"]["OLS all"] == pytest.approx(direct, rel=1e-6)
    # the truth is a linear law of T01 and T04: the referenced peers remove most of the drift
    assert row["rmse_um"]["best-4"] < 0.1 * row["raw_um"]
    assert row["raw_um"] > 10 * row["rmse_um"]["OLS all"]
    assert row["promised_um"]["default"] > 0


def test_undeclared_is_the_default_without_its_bending_axes_no_prefilter_without_the_low_pass(
        tmp_path):
    from thermal_comp.host.train import train_model

    for i, off in enumerate((0.0, 1.0, 3.0)):
        _tiny_run(tmp_path / f"r{i}.csv", i, off)
    train, test = (tmp_path / "r0.csv", tmp_path / "r1.csv"), tmp_path / "r2.csv"
    job = acc.Job("sim_dev", "tiny", tuple(acc.RunSpec(str(p)) for p in train),
                  (acc.RunSpec(str(test)),), ("dy_um", "dz_um"), "start", bending=("dy_um",))
    rows, _ = acc.run_job(job)
    runs = [acc._load(acc.RunSpec(str(p)), ["dy_um", "dz_um"]) for p in train]
    run = acc._load(acc.RunSpec(str(test)), ["dy_um", "dz_um"])
    for column, bending, kw in (("default", ["dy_um"], {}), ("undeclared", [], {}),
                                ("no prefilter", ["dy_um"], {"prefilter_s": 0.0})):
        model = train_model(runs, ["dy_um", "dz_um"], aux=acc.AUX, reference="start",
                            bending=bending, **kw)
        pred = acc.raw_prediction(model, run)
        for row in rows:
            t = row["target"]
            expected = acc.score(run.target(t), pred[t], "start", run.period_s)
            assert row["rmse_um"][column] == pytest.approx(expected, rel=1e-9)
    dy = next(r for r in rows if r["target"] == "dy_um")
    assert dy["rmse_um"]["default"] != pytest.approx(dy["rmse_um"]["undeclared"], rel=1e-6)
    for row in rows:  # the low-pass changes every ridge axis's fit
        assert row["rmse_um"]["default"] != pytest.approx(row["rmse_um"]["no prefilter"],
                                                          rel=1e-6)


def test_peer_validation_refits_each_peer_without_each_fold():
    rng = np.random.default_rng(3)
    n = 300
    X = np.cumsum(rng.normal(size=(n, 6)), axis=0)
    y = 2.0 * X[:, 0] - X[:, 3] + rng.normal(size=n)
    folds = np.repeat([0, 1, 2], n // 3)
    v = acc.peer_validation(X, X, y, folds)
    assert set(v) == set(acc.PEERS)
    sse = 0.0
    for f in range(3):
        tr = folds != f
        A = np.column_stack([X[tr], np.ones(tr.sum())])
        coef, *_ = np.linalg.lstsq(A, y[tr], rcond=None)
        pred = np.column_stack([X[~tr], np.ones((~tr).sum())]) @ coef
        sse += float(np.sum((y[~tr] - pred) ** 2))
    assert v["OLS all"] == pytest.approx(np.sqrt(sse / n), rel=1e-9)
    # out of fold, not the training fit: above the in-sample residual of OLS on everything
    A = np.column_stack([X, np.ones(n)])
    resid = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
    assert v["OLS all"] > np.sqrt(np.mean(resid ** 2))
    # one group left inside a fold: the peer's own settings are chosen on three blocks
    np.testing.assert_array_equal(acc.inner_folds(np.full(6, 4)), [0, 0, 1, 1, 2, 2])
    np.testing.assert_array_equal(acc.inner_folds(np.array([2, 2, 5, 5])), [0, 0, 1, 1])


def test_promised_is_the_nested_error_when_training_reports_one():
    assert acc.promised({"metrics": {"validation_rmse_um": 1.0}}) == 1.0
    assert acc.promised({"metrics": {"validation_rmse_um": 1.0, "promised_rmse_um": 2.5}}) == 2.5
    assert acc.highest_fold({"metrics": {"promised_fold_rmse_um": [2.5, 4.0, 3.0]}}) == 4.0
    assert math.isnan(acc.highest_fold({"metrics": {"validation_rmse_um": 1.0}}))


def test_summary_geomean_loop_and_calibration():
    def case(d, noeff, peer, promised):
        c = acc.CaseResult("fl", "g", "t", "ch1_um", "none")
        c.rmse_um = {"default": d, "no effects": noeff, "paper": d, "OLS all": peer,
                     "HGB": 2 * peer, "best-5": float("nan")}
        c.promised_um = {"default": promised}
        c.highest_fold_um = {"default": 1.5 * promised}
        c.peer_sensors = {"OLS all": 16, "HGB": 3, "best-5": 5}  # OLS on 16 cannot be wired
        # on the training file HGB looked better: the user would have picked it
        c.peer_validation_um = {"OLS all": 0.9, "HGB": 0.5, "best-5": float("nan")}
        return c

    cases = [case(1.0, 1.0, 2.0, 1.5), case(4.0, 3.0, 2.0, 1.0)]
    s = acc.summarise(cases)
    assert s["per_source"]["fl"]["geomean default / best peer"] == pytest.approx(1.0)
    assert cases[1].best_peer == ("OLS all", 2.0)
    assert cases[1].best_box_peer == ("HGB", 4.0) and cases[1].box_ratio() == 1.0
    assert s["per_source"]["fl"]["geomean default / best peer within the box"] == \
        pytest.approx(np.sqrt(0.25 * 1.0))
    assert cases[1].validated_peer == ("HGB", 4.0) and cases[1].validated_ratio() == 1.0
    assert s["per_source"]["fl"]["geomean default / peer picked by validation"] == \
        pytest.approx(np.sqrt(0.25 * 1.0))
    assert s["per_source"]["fl"]["peer picked by validation counts"]["HGB"] == 2
    assert [w["default_um"] for w in s["loop_worse"]] == [4.0]
    assert s["calibration"]["fl"]["within factor 2"] == 1  # 1/1.5 yes, 4/1 no
    assert s["calibration"]["fl"]["optimistic by more than 2"] == 1  # 4 µm where 1 promised
    assert s["calibration"]["fl"]["pessimistic by more than 2"] == 0
    # highest folds 2.25 and 1.5 um: 1 um is inside the first, 4 um above twice the second
    assert s["calibration"]["fl"]["worse than the highest fold"] == 1
    assert s["calibration"]["fl"]["worse than twice the highest fold"] == 1
    assert "loop" in acc.table(cases, s)


def test_strongest_single_peer_is_the_lowest_geomean_to_the_best_per_case():
    # OLS wins one case, LassoCV two; LassoCV is the steadier method, best-5 always skipped
    rows = [(1.0, 1.0, 2.0), (2.0, 8.0, 2.0), (1.0, 4.0, 1.0)]  # default, OLS all, LassoCV
    cases = []
    for d, ols, lasso in rows:
        c = acc.CaseResult("sim_dev", "g", "t", "dy_um", "start")
        c.rmse_um = {"default": d, "no effects": d, "paper": d, "OLS all": ols,
                     "LassoCV": lasso, "best-5": float("nan")}
        cases.append(c)
    s = acc.summarise(cases)["per_source"]["sim_dev"]
    assert s["geomean each peer / best peer"]["OLS all"] == pytest.approx(16 ** (1 / 3))
    assert s["geomean each peer / best peer"]["LassoCV"] == pytest.approx(2 ** (1 / 3))
    assert math.isnan(s["geomean each peer / best peer"]["best-5"])
    assert s["strongest single peer"] == "LassoCV"
    assert s["geomean default / strongest single peer"] == pytest.approx(0.5 ** (1 / 3))
    assert s["geomean default / each peer"]["OLS all"] == pytest.approx((1 / 16) ** (1 / 3))
    assert s["geomean strongest single peer / best peer"] == pytest.approx(2 ** (1 / 3))
    text = acc.table(cases, acc.summarise(cases))
    assert "the strongest single peer, LassoCV" in text


def test_sim_dev_floor_comes_from_the_manifest_of_the_test_run(tmp_path):
    import json

    (tmp_path / "manifest.json").write_text(json.dumps({"scenarios": [
        {"id": "S0", "rmse_um": {"S0_test_P3.csv": {
            "dy": {"oracle": 0.3, "noise_floor": 0.2, "naive_ols_all_sensors": 0.8,
                   "oracle_without_hidden": 0.45}}}}]}))
    run = tmp_path / "S0_test_P3.csv"
    assert acc.manifest_floor(str(run), "dy_um") == {"oracle": 0.3, "noise floor": 0.2,
                                                     "oracle without hidden": 0.45}
    # no score for that axis or run (a training run held out), or no manifest: no floor
    assert acc.manifest_floor(str(run), "dz_um") == {}
    assert acc.manifest_floor(str(tmp_path / "S0_train_P1.csv"), "dy_um") == {}
    assert acc.manifest_floor(str(tmp_path / "sub" / "S0_test_P3.csv"), "dy_um") == {}

    c = acc.CaseResult("sim_dev", "m S0", "S0_test_P3", "dy_um", "start")
    c.rmse_um = {"default": 0.9, "no effects": 0.9, "paper": 1.0, "OLS all": 0.6}
    c.floor_um = acc.manifest_floor(str(run), "dy_um")
    summary = acc.summarise([c])
    s = summary["per_source"]["sim_dev"]
    assert s["geomean default / oracle"] == pytest.approx(3.0)
    assert s["geomean best peer / oracle"] == pytest.approx(2.0)
    assert s["geomean oracle / noise floor"] == pytest.approx(1.5)
    visible = s["against the oracle without hidden parts"]["dy_um"]
    assert visible["cases"] == 1
    assert visible["geomean default / it"] == pytest.approx(2.0)
    assert visible["geomean best peer / it"] == pytest.approx(0.6 / 0.45)
    assert visible["geomean it / noise floor"] == pytest.approx(2.25)
    rows = {r["name"]: r["value"] for r in acc.summary_rows(summary, 1)}
    assert rows["sim_dev: geomean default / its manifest's oracle"] == pytest.approx(3.0)
    assert rows["sim_dev: geomean default / oracle without hidden, dy_um"] == pytest.approx(2.0)
    assert "dy_um against the oracle without hidden parts" in acc.table([c], summary)
    assert rows["sim_dev: geomean default / best peer"] == pytest.approx(1.5)


def test_fl_next_trains_on_the_recording_so_far_and_judges_the_next_cycle():
    jobs = acc.fl_next_jobs()
    assert [j.test[0].start_s for j in jobs] == [2 * acc.FL_CYCLE_S, 3 * acc.FL_CYCLE_S]
    for job in jobs:
        (train,), (test,) = job.train, job.test
        assert train.start_s is None and train.stop_s == test.start_s  # the past, one run
        assert job.reference == "none" and job.targets == tuple(acc.FL_PROBES)
        assert [per_probe for _, per_probe in job.variants] == [True, False]
    assert jobs[0].test[0].stop_s == 3 * acc.FL_CYCLE_S and jobs[-1].test[0].stop_s is None
    # issue 13's target is on the cycles held out in turn; the forward cases are beside it
    c = acc.CaseResult("fl_next", "g", "t", "ch1_um", "none")
    c.rmse_um = {"default": 1.0, "no effects": 1.0, "OLS all": 1.0}
    rows = acc.summary_rows(acc.summarise([c]), 1)
    assert next(r for r in rows if r["name"] == "fl_next: geomean default / best peer"
                )["target"] == ""


def test_a_worker_of_a_shared_pool_trains_its_nested_folds_in_its_own_process(monkeypatch):
    import threadpoolctl

    monkeypatch.setattr(threadpoolctl, "threadpool_limits", lambda n: None)  # this process's
    monkeypatch.setattr(acc, "_FOLD_JOBS", None)  # BLAS threads stay as they are
    assert "jobs" not in acc.train_kwargs("start")  # the bench run alone: the default
    acc._worker_init(shared=True)
    assert acc.train_kwargs("start", ("dy_um",), ("dy_um",)) == {
        "reference": "start", "bending": ["dy_um"], "jobs": 1}
    acc._worker_init(shared=False)  # one worker: its folds may use the other cores
    assert "jobs" not in acc.train_kwargs("start")


def test_other_machines_are_other_simulated_machines_beside_the_target(tmp_path):
    """sim_other: machines the defaults were not chosen on, built as sim's are, no target."""
    from thermal_comp.host.io import load_run

    assert not set(acc.OTHER_SIM_SEEDS) & set(acc.SIM_SEEDS)
    assert "sim_other" in acc.SOURCES and "sim_other" not in acc.TARGET_SOURCES
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    other = acc.sim_jobs(tmp_path / "a", acc.OTHER_SIM_SEEDS[:1], "sim_other")[0]
    tuned = acc.sim_jobs(tmp_path / "b", acc.SIM_SEEDS[:1])[0]
    assert (other.source, tuned.source) == ("sim_other", "sim")
    assert other.group == f"machine {acc.OTHER_SIM_SEEDS[0]}"
    assert other.bending == tuned.bending == acc.BENDING  # the same column, declared alike
    assert [s.label for s in other.train] == [s.label for s in tuned.train]
    # another machine: the same programme, but its sensors sit elsewhere and read otherwise
    a = load_run(other.train[0].path, list(acc.SIM_TARGETS))
    b = load_run(tuned.train[0].path, list(acc.SIM_TARGETS))
    assert a.n_samples == b.n_samples
    assert not np.allclose(a.temperatures, b.temperatures)


def test_intervals_resample_whole_training_sets():
    import itertools

    def case(unit, d, best):
        c = acc.CaseResult("sim_dev", f"{unit} variant", "t", "dy_um", "start", unit)
        c.rmse_um = {"default": d, "no effects": 2 * d, "paper": d, "OLS all": best}
        return c

    # three training sets: one case, two alike cases and three cases of different ratios
    cases = [case("A", 1.0, 2.0), case("B", 3.0, 1.0), case("B", 3.0, 1.0),
             case("C", 1.0, 1.0), case("C", 2.0, 1.0), case("C", 0.5, 1.0)]
    lo, hi = acc.clustered_interval(cases, acc.CaseResult.ratio, draws=200_000)
    # the exact bootstrap distribution: all 27 draws of three sets, equally likely; a draw's
    # geometric mean weighs each set by its cases
    logs = {"A": [math.log(0.5)], "B": [math.log(3.0)] * 2,
            "C": [0.0, math.log(2.0), math.log(0.5)]}
    atoms = np.sort([np.exp(np.mean([x for u in draw for x in logs[u]]))
                     for draw in itertools.product("ABC", repeat=3)])
    cdf = np.arange(1, 28) / 27
    assert lo == pytest.approx(atoms[np.searchsorted(cdf, 0.05)])
    assert hi == pytest.approx(atoms[np.searchsorted(cdf, 0.95)])
    # one set's ratios alike everywhere: no spread, whatever is drawn
    same = [case(u, 1.0, 2.0) for u in "ABCD"]
    assert acc.clustered_interval(same, acc.CaseResult.ratio) == pytest.approx((0.5, 0.5))
    # two training sets say nothing about the spread of others
    assert all(math.isnan(x) for x in acc.clustered_interval(cases[:3], acc.CaseResult.ratio))
    s = acc.summarise(cases)["per_source"]["sim_dev"]["intervals"]
    assert s["training sets"] == 3
    assert s["default / no effects"]["geomean"] == pytest.approx(0.5)
    assert s["default / no effects"]["interval"] == pytest.approx([0.5, 0.5])
    assert "3 of them" in acc.table(cases, acc.summarise(cases))
