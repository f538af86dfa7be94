"""The ridge reads the box's free channels: an L1 ranking of the sensors the selection left out
(host.selection.screening), filled up to the channel budget (host.train.free_channels)."""

from __future__ import annotations

import numpy as np

from thermal_comp.contract.terms import make_lag
from thermal_comp.host.analysis import evaluate_model
from thermal_comp.host.fitting import design_matrix
from thermal_comp.host.io import Run
from thermal_comp.host.selection import fill_free_channels, l1_ranking
from thermal_comp.host.train import train_model

PERIOD = 60.0
N_SENSORS = 12
DRIVERS = {"T03": 1.5, "T05": -1.0, "T08": 1.2, "T10": 0.8, "T11": -0.9}  # um/K


def _temperatures(rng: np.random.Generator, n: int) -> np.ndarray:
    """Independent slow temperatures: random walks smoothed over about an hour."""
    steps = rng.standard_normal((n, N_SENSORS)) * 0.05
    walk = np.cumsum(steps, axis=0)
    kernel = np.ones(60) / 60
    smooth = np.column_stack([np.convolve(walk[:, j], kernel, mode="same")
                              for j in range(N_SENSORS)])
    return 20.0 + smooth


def _run(seed: int, n: int = 2400) -> Run:
    """dz = five sensors' temperatures plus one sensor's 30-min lag, plus probe noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * PERIOD
    T = _temperatures(rng, n)
    names = [f"T{j + 1:02d}" for j in range(N_SENSORS)]
    dz = sum(k * T[:, names.index(s)] for s, k in DRIVERS.items())
    lag = design_matrix([make_lag("T01", 1800.0, PERIOD)], {"T01": T[:, 0]}, PERIOD)[:, 0]
    dz = dz + 2.0 * lag + 0.02 * rng.standard_normal(n)
    return Run(f"day{seed}.csv", t, names, T, ["dz_um"], (dz - dz[0])[:, None])


def test_l1_ranking_puts_the_sensors_that_drive_the_axis_first():
    run = _run(1)
    ranking = l1_ranking([run], "dz_um", run.sensor_names, period_s=PERIOD,
                         taus=(900.0, 3600.0), n_blocks=3)
    assert sorted(ranking) == sorted(run.sensor_names)  # every sensor, each once
    # T01 drives the axis only through its lag: the ranking weighs a sensor's lags too
    assert set(ranking[:6]) == {*DRIVERS, "T01"}


def test_fill_takes_each_axis_best_in_turn_up_to_the_budget():
    rankings = [["A", "B", "C", "D"], ["E", "B", "F"]]
    assert fill_free_channels(["A"], rankings, 4) == ["B", "E", "C"]
    assert fill_free_channels(["A"], rankings, 10) == ["B", "E", "C", "F", "D"]  # all there is
    assert fill_free_channels(["A", "B", "C"], rankings, 3) == []


def test_the_ridge_reads_the_free_channels_and_predicts_an_unseen_day_better():
    train, test = [_run(2), _run(3)], _run(4)
    kw = dict(effects=False, max_sensors=2, reference="start", nested=False)
    filled = train_model(train, ["dz_um"], **kw)
    alone = train_model(train, ["dz_um"], **kw, fill_channels=False)
    ols = train_model(train, ["dz_um"], **kw, fit="ols")
    assert len(filled["channels"]) == 8  # the box's eight inputs, all read
    assert len(alone["channels"]) <= 2 and len(ols["channels"]) <= 2
    axis = filled["axes"]["dz_um"]
    extra = axis["fit"]["free_channels_read"]
    assert len(extra) == 8 - len(alone["channels"])
    assert not set(extra) & {c["sensor"] for c in alone["channels"]}
    kinds = {(t["kind"], t["source"]) for t in axis["terms"] if "source" in t}
    assert all(("temp", s) in kinds and ("lag", s) in kinds for s in extra)  # and its lags
    # five sensors drive the axis: the two selected cannot carry it, the filled box can
    err = {name: evaluate_model(m, test)["axes"]["dz_um"]["rmse_um"]
           for name, m in (("filled", filled), ("alone", alone))}
    assert err["filled"] < 0.5 * err["alone"], err
    small = train_model(train, ["dz_um"], **kw, max_channels=6)
    assert len(small["channels"]) == 6
