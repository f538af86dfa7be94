"""The metrologist's numbers: coefficient standard errors against scipy's linregress, the
AR(1) inflation, ISO 230-3 drift figures on a ramp, the equation text and the wiring sheet."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from host.analysis.metrology import coefficient_table, iso230_drift, wiring_rows
from host.io import Run


def _run(t: np.ndarray, temp: np.ndarray, y: np.ndarray) -> Run:
    return Run(path="r.csv", time_s=t, temperatures=temp[:, None], sensor_names=["T01"],
               displacements=y[:, None], target_names=["dz_um"])


def test_standard_errors_match_scipy_linregress():
    rng = np.random.default_rng(4)
    t = np.arange(400) * 60.0
    temp = 20 + 5 * np.sin(t / 3000.0) + rng.normal(0, 0.05, t.size)
    y = 3.0 + 1.7 * temp + rng.normal(0, 0.3, t.size)
    fit = stats.linregress(temp, y)
    axis = {"intercept": fit.intercept,
            "terms": [{"kind": "temp", "source": "T01", "coef": fit.slope}],
            "metrics": {"vif": {"T01": 1.0}, "condition_number": 1.0}}
    table = coefficient_table("dz_um", axis, [_run(t, temp, y)], 60.0)
    intercept, slope = table["rows"]
    assert slope["se"] == pytest.approx(fit.stderr, rel=1e-9)
    assert intercept["se"] == pytest.approx(fit.intercept_stderr, rel=1e-9)
    assert slope["unit"] == "µm/K" and intercept["unit"] == "µm"
    e = y - (fit.intercept + fit.slope * temp)
    e = e - e.mean()
    rho = float(e[1:] @ e[:-1] / (e @ e))
    assert table["residual_lag1"] == pytest.approx(rho, rel=1e-9)
    assert slope["se_ar1"] == pytest.approx(fit.stderr * math.sqrt((1 + rho) / (1 - rho)))
    # digits follow the standard error: 0.090 -> three decimals
    assert table["equation"].startswith(f"δ(dz_um) = {fit.intercept:.3f}(±")
    assert "·T01" in table["equation"] and "(±" in table["equation"]


def test_iso230_drift_of_a_ramp_and_a_warm_up():
    t = np.arange(0, 5 * 3600 + 1, 60.0)
    ramp = iso230_drift(t, t / 3600.0)  # 1 um per hour for 5 h
    assert ramp == pytest.approx({"max_um": 5.0, "first_hour_um": 1.0, "start_to_end_um": 5.0,
                                  "hours": 5.0})
    warm = 10 * (1 - np.exp(-t / 1800.0))  # most of the drift in the first hour
    d = iso230_drift(t, warm)
    assert d["first_hour_um"] == pytest.approx(10 * (1 - math.exp(-2)))
    assert d["max_um"] == pytest.approx(d["start_to_end_um"])


def test_wiring_sheet_lists_channels_in_order_with_their_readers():
    model = {"channels": [{"channel": 1, "sensor": "T12", "tc_type": "J"},
                          {"channel": 0, "sensor": "T05", "tc_type": "K",
                           "trained_min_c": 20.0, "trained_max_c": 30.0}],
             "axes": {"dx_um": {"terms": [{"kind": "temp", "source": "T05"}]},
                      "dz_um": {"terms": [{"kind": "lag", "source": "T12"},
                                          {"kind": "temp", "source": "T05"}]}}}
    rows = wiring_rows(model, {"T12": "spindle housing, front"})
    assert [(r["channel"], r["sensor"], r["tc_type"]) for r in rows] == [(0, "T05", "K"),
                                                                         (1, "T12", "J")]
    assert rows[0]["axes"] == ["dx_um", "dz_um"] and rows[1]["axes"] == ["dz_um"]
    assert rows[1]["location"] == "spindle housing, front" and rows[0]["location"] is None
