"""`host train` / `host evaluate` / `host split`: model contents, metrics recomputed with numpy,
channel wiring, atomic output, CLI shapes and an end-to-end run on the real FL_THERMAL data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from thermal_comp.contract.model_file import ModelFormatError, read_model, write_model
from thermal_comp.host.analysis import evaluate_model, predict
from thermal_comp.host.cli import main
from thermal_comp.host.io import Run, load_run, write_run
from thermal_comp.host.train import TrainingError, train_model

ROOT = Path(__file__).resolve().parents[3]
FL = ROOT / "examples" / "fl_thermal_steps.csv"


def _heat(power: np.ndarray, tau: float, dt: float) -> np.ndarray:
    a = 1 - np.exp(-dt / tau)
    out = np.zeros_like(power)
    for i in range(1, len(power)):
        out[i] = out[i - 1] + a * (power[i] - out[i - 1])
    return out


def _run(path: str, power: np.ndarray, seed: int, dt: float = 60.0) -> Run:
    """Two heat sources (fast spindle, slow frame); 8 sensors, 4 on each; two axes."""
    rng = np.random.default_rng(seed)
    fast = 8 * _heat(power, 600.0, dt)
    slow = 5 * _heat(power, 4000.0, dt)
    T = np.column_stack([20 + fast * g + 0.02 * rng.normal(size=len(power))
                         for g in (1.0, 0.9, 0.8, 0.7)] +
                        [20 + slow * g + 0.02 * rng.normal(size=len(power))
                         for g in (1.0, 0.95, 0.85, 0.75)])
    dz = 3.0 * fast - 1.5 * slow + 0.05 * rng.normal(size=len(power))
    dy = 1.0 * slow + 0.05 * rng.normal(size=len(power))
    t = np.arange(len(power)) * dt
    return Run(path, t, [f"T{i:02d}" for i in range(1, 9)], T, ["dz_um", "dy_um"],
               np.column_stack([dz, dy]))


def _power(kind: str, n: int = 600) -> np.ndarray:
    t = np.arange(n)
    if kind == "steps":
        return np.where(t < n // 2, ((t // 75) % 4 + 1) / 4.0, 0.0)
    return np.where(t < n // 2, 0.5 + 0.5 * np.sin(2 * np.pi * t / 140.0), 0.0)


@pytest.fixture(scope="module")
def runs() -> list[Run]:
    return [_run("a.csv", _power("steps"), 1), _run("b.csv", _power("sine"), 2)]


def test_model_fits_and_metrics_match_numpy(runs):
    model = train_model(runs, ["dz_um", "dy_um"], effects=False, groups=4,
                        reference="none",
        fit="ols", nested=False)  # the least-squares arithmetic itself
    assert model["schema"] == "thermal-model/1" and model["sample_period_s"] == 60.0
    for axis in ("dz_um", "dy_um"):
        spec = model["axes"][axis]
        sensors = spec["selection"]["sensors"]
        assert [t["source"] for t in spec["terms"]] == sensors
        idx = [runs[0].sensor_names.index(s) for s in sensors]
        X = np.vstack([r.temperatures[:, idx] for r in runs])
        y = np.concatenate([r.target(axis) for r in runs])
        A = np.column_stack([np.ones(len(y)), X])
        beta, *_ = np.linalg.lstsq(A, y, rcond=None)
        np.testing.assert_allclose([spec["intercept"], *(t["coef"] for t in spec["terms"])],
                                   beta, rtol=1e-6, atol=1e-6)
        m = spec["metrics"]
        assert m["train_rmse_um"] == pytest.approx(np.sqrt(np.mean((y - A @ beta) ** 2)))
        # leave-one-run-out, recomputed here
        sq = []
        for k in range(2):
            rows = np.r_[np.full(runs[0].n_samples, 0), np.full(runs[1].n_samples, 1)] == k
            b, *_ = np.linalg.lstsq(A[~rows], y[~rows], rcond=None)
            sq.append((y[rows] - A[rows] @ b) ** 2)
        assert m["validation_rmse_um"] == pytest.approx(np.sqrt(np.mean(np.concatenate(sq))))
        assert m["raw_rms_um"] == pytest.approx(np.sqrt(np.mean(y ** 2)))
        assert "leave-one-run-out" in m["validation"]
        assert m["validation_rmse_um"] < 0.1 * m["raw_rms_um"]
    # dz needs both sources, dy only the slow one
    dz = model["axes"]["dz_um"]["selection"]["sensors"]
    assert {int(s[1:]) <= 4 for s in dz} == {True, False}


def test_channels_are_the_union_in_column_order_and_can_be_overridden(runs):
    model = train_model(runs, ["dz_um", "dy_um"], effects=False, groups=4, fit="ols", nested=False)
    used = sorted({t["source"] for a in model["axes"].values() for t in a["terms"]})
    assert [c["sensor"] for c in model["channels"]] == used  # column order = name order here
    assert [c["channel"] for c in model["channels"]] == list(range(len(used)))
    last = used[-1]
    model2 = train_model(runs, ["dz_um", "dy_um"], effects=False, groups=4,
                         channels={last: 0}, fit="ols", nested=False)
    wiring = {c["sensor"]: c["channel"] for c in model2["channels"]}
    assert wiring[last] == 0
    assert sorted(wiring.values()) == list(range(len(used)))
    with pytest.raises(TrainingError, match="no axis uses sensor 'T99'"):
        train_model(runs, ["dz_um"], effects=False, groups=4, channels={"T99": 0},
                    fit="ols", nested=False)


def test_paper_and_validated_methods_are_both_available(runs):
    for method in ("paper", "validated"):
        model = train_model(runs, ["dz_um"], effects=False, groups=4, selection=method,
                            fit="ols", nested=False)
        sel = model["axes"]["dz_um"]["selection"]
        assert sel["method"] == method
        assert len(sel["ec_curve"]) == len(sel["representatives"])
        assert 1 <= sel["chosen_count"] <= 5
    with pytest.raises(TrainingError, match="unknown --selection"):
        train_model(runs, ["dz_um"], selection="magic", fit="ols", nested=False)


def test_model_roundtrip_and_atomic_write(runs, tmp_path):
    model = train_model(runs, ["dz_um"], effects=False, groups=4, fit="ols", nested=False)
    path = tmp_path / "out" / "model.json"
    write_model(model, path)
    assert read_model(path)["axes"]["dz_um"]["terms"] == model["axes"]["dz_um"]["terms"]
    assert [p.name for p in path.parent.iterdir()] == ["model.json"]  # no temp file left
    bad = json.loads(path.read_text())
    bad["axes"]["dz_um"]["terms"][0]["source"] = "T77"
    with pytest.raises(ModelFormatError, match="'T77' is not in 'channels'"):
        write_model(bad, path)
    assert read_model(path) == json.loads(path.read_text())  # old file untouched


def test_evaluate_metrics_recomputed_independently(runs):
    model = train_model(runs[:1], ["dz_um"], effects=False, groups=4,
                        reference="none",
        fit="ols", nested=False)  # the least-squares arithmetic itself
    test = _run("c.csv", _power("sine", 500) * 0.8, 3)
    result = evaluate_model(model, test)
    spec = model["axes"]["dz_um"]
    idx = [test.sensor_names.index(t["source"]) for t in spec["terms"]]
    pred = spec["intercept"] + test.temperatures[:, idx] @ [t["coef"] for t in spec["terms"]]
    np.testing.assert_allclose(predict(model, test)["dz_um"], pred)
    y = test.target("dz_um")
    m = result["axes"]["dz_um"]
    assert m["rmse_um"] == pytest.approx(np.sqrt(np.mean((y - pred) ** 2)))
    assert m["max_abs_um"] == pytest.approx(np.max(np.abs(y - pred)))
    assert m["raw_rms_um"] == pytest.approx(np.sqrt(np.mean(y ** 2)))
    assert m["raw_peak_um"] == pytest.approx(np.max(np.abs(y)))
    assert m["reduction_pct"] == pytest.approx(100 * (1 - m["rmse_um"] / m["raw_rms_um"]))
    assert m["reduction_pct"] > 80


def _write(run: Run, path: Path) -> None:
    cols = {n: run.temperatures[:, i] for i, n in enumerate(run.sensor_names)}
    cols.update({n: run.displacements[:, i] for i, n in enumerate(run.target_names)})
    write_run(path, run.time_s, cols)


def test_cli_train_json_shape_and_evaluate(runs, tmp_path, capsys):
    paths = [tmp_path / "a.csv", tmp_path / "b.csv"]
    for run, p in zip(runs, paths, strict=True):
        _write(run, p)
    out = tmp_path / "build"
    code = main(["train",
                 "--fit", "ols", "--no-nested",
                 *map(str, paths), "--target", "dz_um", "--target", "dy_um",
                 "--groups", "4", "--out", str(out), "--no-codegen", "--json"])
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["model"] == str(out / "model.json")
    for axis in ("dz_um", "dy_um"):
        a = doc["axes"][axis]
        assert set(a) >= {"sensors", "train_rmse_um", "validation_rmse_um", "raw_rms_um"}
        assert all(s.startswith("T") for s in a["sensors"])
    assert main(["evaluate", str(out / "model.json"), str(paths[1]), "--json"]) == 0
    ev = json.loads(capsys.readouterr().out)
    assert set(ev["axes"]["dz_um"]) >= {"rmse_um", "max_abs_um", "raw_rms_um", "raw_peak_um",
                                        "reduction_pct"}


def test_cli_train_prints_the_filter_states_the_axes_share(runs, tmp_path, capsys):
    paths = [tmp_path / "a.csv", tmp_path / "b.csv"]
    for run, p in zip(runs, paths, strict=True):
        _write(run, p)
    out = tmp_path / "ridge"
    assert main(["train", "--no-nested", *map(str, paths), "--target", "dz_um", "--target",
                 "dy_um", "--out", str(out), "--no-codegen"]) == 0
    printed = capsys.readouterr().out
    model = read_model(out / "model.json")
    lags = [(t["source"], t["tau_s"]) for a in model["axes"].values() for t in a["terms"]
            if t["kind"] in ("lag", "rate")]
    assert len(lags) > len(set(lags))  # both axes read the pool: terms outnumber the states
    assert f"filter states: {len(set(lags))} of 32 " in printed
    assert "one training run" not in printed  # two runs: no hint to add a day


def test_cli_train_on_one_run_suggests_a_second_day(runs, tmp_path, capsys):
    p = tmp_path / "a.csv"
    _write(runs[0], p)
    assert main(["train", "--fit", "ols", "--no-nested", str(p), "--target", "dz_um",
                 "--out", str(tmp_path / "one"), "--no-codegen"]) == 0
    printed = capsys.readouterr().out
    assert "one training run:" in printed and "a second day" in printed


def test_cli_errors_are_clear(runs, tmp_path, capsys):
    p = tmp_path / "a.csv"
    _write(runs[0], p)
    assert main(["train",
                 "--fit", "ols", "--no-nested", str(p), "--target", "nope_um", "--no-codegen"]) == 2
    assert "column 'nope_um'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["train",
              "--fit", "ols", "--no-nested", str(p), "--target", "dz_um", "--channel", "T01=x"])
    assert exc.value.code == 2 and "SENSOR=INDEX" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "missing.json"), str(p)]) == 2
    assert "model file not found" in capsys.readouterr().err


def test_fast_csv_path_reads_exactly_what_the_careful_reader_reads(tmp_path, monkeypatch):
    import thermal_comp.host.io.table as table_module

    path = tmp_path / "r.csv"
    rng = np.random.default_rng(9)
    write_run(path, np.arange(50.0), {"T1": rng.normal(size=50) * 1e3, "T2": rng.normal(size=50),
                                      "dz_um": np.linspace(-1, 1, 50)}, precision=17)
    fast = table_module.read_table(path)
    monkeypatch.setattr(table_module, "read_plain_table", lambda p: None)
    slow = table_module.read_table(path)
    assert fast[0] == slow[0]
    np.testing.assert_array_equal(fast[1], slow[1])
    np.testing.assert_array_equal(fast[2], slow[2])


def test_end_to_end_fl_thermal_split_train_evaluate(tmp_path, capsys):
    """Real data: train on the first three heat/cool cycles, judge on the fourth (5000 rpm)."""
    assert main(["split", str(FL), "--at-hours", "24", "-o", str(tmp_path), "--json"]) == 0
    parts = [Path(p) for p in json.loads(capsys.readouterr().out)["parts"]]
    assert len(parts) == 2
    whole = load_run(FL, ["ch3_um"])
    first = load_run(parts[0], ["ch3_um"])
    second = load_run(parts[1], ["ch3_um"])
    assert first.n_samples + second.n_samples == whole.n_samples
    assert first.time_s[-1] < 24 * 3600 <= second.time_s[0]
    np.testing.assert_allclose(second.temperatures, whole.temperatures[first.n_samples:])
    out = tmp_path / "model"
    assert main(["train",
                 "--fit", "ols", "--no-nested",
                 str(parts[0]), "--target", "ch3_um", "--out", str(out),
                 "--reference", "none", "--no-codegen", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["axes"]["ch3_um"]["sensors"]
    selected = read_model(out / "model.json")["axes"]["ch3_um"]["selection"]["sensors"]
    assert 1 <= len(selected) <= 5
    assert main(["evaluate", str(out / "model.json"), str(parts[1]), "--json"]) == 0
    m = json.loads(capsys.readouterr().out)["axes"]["ch3_um"]
    # the uncompensated drift of the 5000 rpm cycle is ~45 um RMS; the model removes most
    assert m["raw_rms_um"] > 40
    assert m["rmse_um"] < 0.3 * m["raw_rms_um"]


def test_end_to_end_simulated_machine_other_speed_profile(tmp_path, capsys):
    """Select and fit on a constant-speed run, judge on a random-speed run of the same
    simulated machine (host.sim.simulator); the residual must be near the probes' noise."""
    sim = pytest.importorskip("thermal_comp.host.sim.simulator")
    programs = pytest.importorskip("thermal_comp.host.sim.spindle_programs")
    paths = {}
    for name, seed in (("constant", 1), ("random", 2)):
        run = sim.simulate(programs.build_program(name, hours=6, cool_hours=6, seed=seed),
                           sim.SimConfig(dt_s=60.0, seed=seed))
        paths[name] = tmp_path / f"sim_{name}.csv"
        write_run(paths[name], run.time_s, run.columns)
    out = tmp_path / "model"
    assert main(["train", "--fit", "ols", "--no-nested",
                 str(paths["constant"]), "--target", "dz_um", "--target", "dy_um",
                 "--out", str(out), "--no-codegen", "--json"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(out / "model.json"), str(paths["random"]), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)["axes"]
    for axis in ("dz_um", "dy_um"):
        m = result[axis]
        assert m["raw_rms_um"] > 3.0
        assert m["reduction_pct"] > 95.0, (axis, m)


@pytest.mark.parametrize("selection", ["validated", "paper"])
def test_example_simulations_train_on_two_protocols_judge_on_random(selection):
    """The demo's setup with the committed example runs (lag, ambient... effects included):
    the static baseline alone already removes most of the drift of the unseen random run."""
    paths = [ROOT / "examples" / f"sim_{p}.csv" for p in ("constant", "step", "random")]
    if not all(p.is_file() for p in paths):
        pytest.skip("example simulations not generated (make examples)")
    axes = ["dx_um", "dy_um", "dz_um"]
    model = train_model(paths[:2], axes, effects=False, selection=selection,
                        fit="ols", nested=False)
    test = load_run(paths[2], axes, model["training"]["sensors"])
    result = evaluate_model(model, test)["axes"]
    k = model["reference"]["samples"]
    for axis in axes:
        y = test.target(axis)
        y = y - np.array([y[:min(i, k - 1) + 1].mean() for i in range(y.size)])  # since start
        pred = predict(model, test)[axis]
        assert pred[0] == 0.0  # the box's output at its first sample after zeroing
        assert result[axis]["rmse_um"] == pytest.approx(np.sqrt(np.mean((y - pred) ** 2)))
        assert result[axis]["reduction_pct"] > 90.0, (axis, result[axis])
        assert 1 <= len(model["axes"][axis]["selection"]["sensors"]) <= 5


def test_training_runs_blas_on_one_thread_and_gives_the_callers_threads_back(runs,
                                                                            monkeypatch):
    from threadpoolctl import threadpool_info, threadpool_limits

    import thermal_comp.host.train.next_day_fit as next_day_fit
    import thermal_comp.host.train.pipeline as pipeline

    def blas() -> dict[str, int]:
        return {i["filepath"]: i["num_threads"] for i in threadpool_info()
                if i["user_api"] == "blas"}

    if not blas():
        pytest.skip("no BLAS library that threadpoolctl controls")
    inside = []
    fit = next_day_fit.fit_for_the_next_day  # late in training: scipy and scikit-learn at work

    def record(*args, **kwargs):
        inside.append(blas())
        return fit(*args, **kwargs)

    monkeypatch.setattr(next_day_fit, "fit_for_the_next_day", record)
    with threadpool_limits(limits=2, user_api="blas"):  # the caller's setting, on any machine
        before = blas()
        train_model(runs, ["dz_um"], effects=False, nested=False, reference="none")
        after = blas()
    assert inside and set(inside[0].values()) == {pipeline.BLAS_THREADS}
    assert {lib: n for lib, n in after.items() if lib in before} == before
