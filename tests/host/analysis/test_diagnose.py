"""`host diagnose` on synthetic runs with a known fault or a known missing effect.

A small machine: three thermal nodes (spindle, column, base) each read by two thermocouples
(near-duplicates: each other's cluster-mates), plus shop air. The faults are written into
the judging run by hand (a drift ramp, a frozen reading, extra noise), so the expectation is
the construction itself.
"""

from __future__ import annotations

import contextlib
import io
import json
import math

import numpy as np
import pytest

from thermal_comp.contract.model_file import write_model
from thermal_comp.host.analysis import (
    DiagnoseError,
    check_sensor,
    diagnose,
    load_for_diagnosis,
    summary_lines,
)
from thermal_comp.host.cli import main
from thermal_comp.host.io import Run, write_run
from thermal_comp.host.train import train_model

DT = 60.0


def lowpass(x: np.ndarray, tau: float) -> np.ndarray:
    a = 1.0 - math.exp(-DT / tau)
    y = np.empty_like(x)
    y[0] = x[0]
    for i in range(1, x.size):
        y[i] = y[i - 1] + a * (x[i] - y[i - 1])
    return y


def machine_run(seed: int, hours: float = 10.0, speed_um_per_krpm: float = 0.0) -> Run:
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 / DT)
    t = np.arange(n) * DT
    rpm = np.zeros(n)
    i = 20
    while i < n:
        length = int(rng.integers(20, 70))
        rpm[i:i + length] = rng.choice([0.0, 2000.0, 4000.0, 6000.0])
        i += length
    amb = 20.0 + 0.8 * np.sin(2 * np.pi * t / 86400 + rng.uniform(0, 6.3))
    spindle = lowpass(amb + 15.0 * rpm / 6000.0, 900.0)
    column = lowpass(amb + 6.0 * rpm / 6000.0, 2 * 3600.0)
    base = lowpass(amb + 3.0 * rpm / 6000.0, 5 * 3600.0)
    temps = {"T1": spindle, "T2": 0.97 * spindle + 0.03 * column, "T3": column,
             "T4": 0.95 * column + 0.05 * base, "T5": base, "T6": 0.97 * base + 0.03 * amb,
             "T_amb": amb}
    temps = {k: np.round((v + rng.normal(0, 0.01, n)) * 128) / 128 for k, v in temps.items()}
    d = 4.0 * (spindle - 20) + 2.0 * (column - 20) - 1.0 * (base - 20)
    d = d + speed_um_per_krpm * rpm / 1000.0 + rng.normal(0, 0.1, n)
    names = list(temps)
    return Run(f"machine_{seed}", t, names, np.column_stack([temps[k] for k in names]),
               ["dz_um"], d[:, None], ["spindle_rpm"], rpm[:, None])


@pytest.fixture(scope="module")
def model():
    return train_model([machine_run(1)], ["dz_um"], aux=["spindle_rpm"], max_sensors=3,
                       fit="ols", nested=False)


def with_sensor(run: Run, sensor: str, values: np.ndarray) -> Run:
    temps = run.temperatures.copy()
    temps[:, run.sensor_names.index(sensor)] = values
    return Run(run.path, run.time_s, list(run.sensor_names), temps, list(run.target_names),
               run.displacements.copy(), list(run.aux_names), run.aux)


def model_sensor(model: dict) -> str:
    """A sensor the model reads that has a near-duplicate mate (T1/T3/T5)."""
    channels = [c["sensor"] for c in model["channels"]]
    return next(s for s in ("T1", "T3", "T5", "T2", "T4", "T6") if s in channels)


def test_clean_run_no_fault_and_error_near_validation(model):
    doc = diagnose(model, machine_run(2))
    assert doc["faulty"] == []
    ax = doc["axes"]["dz_um"]
    assert ax["rmse_um"] < 5 * model["axes"]["dz_um"]["metrics"]["validation_rmse_um"] + 0.2
    assert all(c["status"] == "ok" for c in doc["sensors"].values())


def test_drifting_sensor_is_named_with_its_size(model):
    s = model_sensor(model)
    run = machine_run(3)
    rate_c_per_h = 0.3
    drifted = with_sensor(run, s, run.column(s) + rate_c_per_h * run.time_s / 3600)
    doc = diagnose(model, drifted)
    assert [(f["sensor"], f["fault"]) for f in doc["faulty"]] == [(s, "drifting")]
    ev = doc["sensors"][s]["evidence"]
    assert ev["drift_c"] == pytest.approx(rate_c_per_h * run.time_s[-1] / 3600, rel=0.2)
    assert ev["drift_consistent"] is True
    assert ev["reference"] == "training"
    # the error it causes is a slow trend: the drift kind explains the residual
    assert doc["axes"]["dz_um"]["explained_by"][0]["kind"] == "drift"


def test_stuck_sensor(model):
    s = model_sensor(model)
    run = machine_run(4)
    x = run.column(s).copy()
    k = int(0.55 * x.size)
    x[k:] = x[k]
    doc = diagnose(model, with_sensor(run, s, x))
    faults = {(f["sensor"], f["fault"]) for f in doc["faulty"]}
    assert (s, "stuck") in faults
    ev = doc["sensors"][s]["evidence"]
    assert ev["stuck_at_c"] == x[k]
    assert ev["stuck_s"] == pytest.approx(run.time_s[-1] - run.time_s[k])


def test_noisy_sensor(model):
    s = model_sensor(model)
    run = machine_run(5)
    noisy = run.column(s) + np.random.default_rng(9).normal(0, 0.3, run.n_samples)
    doc = diagnose(model, with_sensor(run, s, noisy))
    assert (s, "noisy") in {(f["sensor"], f["fault"]) for f in doc["faulty"]}
    assert doc["sensors"][s]["evidence"]["noise_c"] == pytest.approx(0.3, rel=0.25)


def test_a_missing_speed_effect_is_named(model):
    doc = diagnose(model, machine_run(6, speed_um_per_krpm=1.5))
    ax = doc["axes"]["dz_um"]
    assert ax["explained_by"] and ax["explained_by"][0]["kind"] == "speed"
    assert ax["explained_by"][0]["rmse_after_um"] < 0.5 * ax["explained_by"][0]["rmse_before_um"]


def test_without_training_reference_drift_after_the_first_third(model):
    bare = json.loads(json.dumps(model))
    for spec in bare["axes"].values():
        spec.pop("sensor_reference", None)
    s = model_sensor(model)
    run = machine_run(7)
    t_h = run.time_s / 3600
    ramp = np.clip(t_h - t_h[-1] / 3, 0, None) * 0.5
    res = check_sensor(with_sensor(run, s, run.column(s) + ramp), s, None,
                       [m for g in bare["axes"]["dz_um"]["selection"]["groups"] if s in g
                        for m in g if m != s] or ["T2"])
    assert res["evidence"]["reference"] == "first third of run"
    assert res["status"] == "drifting"


def test_cli_text_json_and_missing_column(model, tmp_path):
    mpath = tmp_path / "model.json"
    write_model(model, mpath)
    run = machine_run(8)
    cols = {n: run.column(n) for n in [*run.sensor_names, "spindle_rpm", "dz_um"]}
    good = tmp_path / "run.csv"
    write_run(good, run.time_s, cols)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["diagnose", str(mpath), str(good)]) == 0
    text = out.getvalue()
    assert "dz_um: error RMSE" in text and "none looks faulty" in text
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["diagnose", str(mpath), str(good), "--json"]) == 0
    doc = json.loads(out.getvalue())
    assert doc["model"] == str(mpath) and "dz_um" in doc["axes"]
    s = model_sensor(model)
    bad = tmp_path / "bad.csv"
    write_run(bad, run.time_s, {k: v for k, v in cols.items() if k != s})
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["diagnose", str(mpath), str(bad)]) == 2
    assert f"missing sensor column(s) {s}" in err.getvalue() and "bad.csv" in err.getvalue()


def test_run_without_the_axis_still_checks_sensors(model, tmp_path):
    run = machine_run(9)
    path = tmp_path / "nodisp.csv"
    write_run(path, run.time_s, {n: run.column(n) for n in [*run.sensor_names, "spindle_rpm"]})
    loaded = load_for_diagnosis(model, path)
    doc = diagnose(model, loaded)
    assert doc["axes"] == {} and doc["axes_without_measurement"] == ["dz_um"]
    assert any("not measured" in line for line in summary_lines(doc))


def test_period_mismatch_is_refused(model):
    run = machine_run(10, hours=4)
    slow = Run(run.path, run.time_s * 2, run.sensor_names, run.temperatures, run.target_names,
               run.displacements, run.aux_names, run.aux)
    with pytest.raises(DiagnoseError, match="sample period 120 s differs"):
        diagnose(model, slow)
