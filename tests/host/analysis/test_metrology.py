"""The metrologist's numbers: coefficient standard errors against scipy's linregress, the
AR(1) inflation, ISO 230-3 drift figures on a ramp, the equation text and the wiring sheet."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from thermal_comp.host.analysis.metrology import coefficient_table, iso230_drift, wiring_rows
from thermal_comp.host.io import Run


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


def _lagged(x: np.ndarray, alpha: float) -> np.ndarray:
    out = np.empty_like(x)
    out[0] = x[0]
    for k in range(1, len(x)):
        out[k] = out[k - 1] + alpha * (x[k] - out[k - 1])
    return out


def test_sensor_gains_sum_temperature_and_lags_and_a_rate_settles_to_nothing():
    from thermal_comp.contract.terms import Term
    from thermal_comp.host.analysis.metrology import sensor_gains

    terms = [Term.from_json(t) for t in (
        {"kind": "temp", "source": "T01"},
        {"kind": "lag", "source": "T01", "tau_s": 900.0, "alpha": 0.1},
        {"kind": "rate", "source": "T01", "tau_s": 300.0, "alpha": 0.2},
        {"kind": "lag", "source": "T02", "tau_s": 3600.0, "alpha": 0.01})]
    g1, g2 = sensor_gains(terms, [1.5, -0.5, 2.0, 0.7])
    assert g1["steady_um_per_k"] == pytest.approx(1.0)  # 1.5 - 0.5; the rate's 2.0 settles
    assert g1["immediate_um_per_k"] == pytest.approx(3.5)  # temp + rate at once
    assert g1["modes"] == [{"tau_s": 300.0, "amplitude_um_per_k": -2.0},
                           {"tau_s": 900.0, "amplitude_um_per_k": -0.5}]
    assert g2 == {"sensor": "T02", "immediate_um_per_k": 0.0, "steady_um_per_k": 0.7,
                  "modes": [{"tau_s": 3600.0, "amplitude_um_per_k": 0.7}], "curvature": []}
    # the step response the modes describe, against the features themselves
    alpha_lag, alpha_rate = 0.1, 0.2
    step = np.r_[np.zeros(5), np.ones(4000)]
    y = (1.5 * step - 0.5 * _lagged(step, alpha_lag)
         + 2.0 * (step - _lagged(step, alpha_rate)))
    assert y[5] == pytest.approx(1.5 + 2.0 * (1 - alpha_rate) - 0.5 * alpha_lag)
    assert y[-1] == pytest.approx(g1["steady_um_per_k"], abs=1e-9)


def test_ridge_refit_is_fit_ridge_at_its_alpha_and_its_dof_is_the_hat_trace():
    from thermal_comp.host.analysis.metrology import ridge_refit
    from thermal_comp.host.fitting import fit_ridge

    rng = np.random.default_rng(7)
    n = 300
    base = rng.normal(size=(n, 1))
    X = np.column_stack([base + 0.01 * rng.normal(size=(n, 1)) for _ in range(3)]
                        + [rng.normal(size=(n, 1)) * 50])
    y = X[:, 0] - X[:, 1] + 0.02 * X[:, 3] + rng.normal(0, 0.1, n)
    shared = [True, True, True, False]
    groups = np.repeat(np.arange(3), n // 3)
    ref = fit_ridge(X, y, groups, alphas=(0.01,), shared=shared)
    mine = ridge_refit(X, y, 0.01, shared)
    np.testing.assert_allclose(mine.coef, ref.coef, rtol=1e-10, atol=1e-12)
    assert mine.intercept == pytest.approx(ref.intercept)
    # the hat matrix written out: prediction = H y, linear in y
    H = np.column_stack([ridge_refit(X, e, 0.01, shared).coef @ X.T
                         + ridge_refit(X, e, 0.01, shared).intercept for e in np.eye(n)])
    assert mine.effective_dof == pytest.approx(float(np.trace(H)), rel=1e-8)
    assert 1 < mine.effective_dof < 5  # shrunk below the 5 coefficients, above the intercept
    assert ridge_refit(X, y, 0.0, shared).effective_dof == pytest.approx(5.0)


def _table(axis: dict, t: np.ndarray, temp: np.ndarray, y: np.ndarray) -> dict:
    return coefficient_table("dz_um", axis, [_run(t, temp, y)], 60.0)


def test_a_fit_whose_coefficients_are_all_below_their_errors_is_named_not_identifiable():
    rng = np.random.default_rng(3)
    t = np.arange(300) * 60.0
    temp = 20 + 0.01 * rng.normal(size=t.size)  # the temperature barely moves
    noise = rng.normal(0, 1.0, t.size)
    A = np.column_stack([np.ones(t.size), temp])
    y = noise - A @ np.linalg.lstsq(A, noise, rcond=None)[0] + 0.1 * A @ [1.0, 0.01]
    fit = stats.linregress(temp, y)  # 0.1 ± about 30 and 0.001 ± about 1.5
    axis = {"intercept": fit.intercept, "fit": {"family": "ols"},
            "terms": [{"kind": "temp", "source": "T01", "coef": fit.slope}],
            "metrics": {"vif": {"T01": 1.0}}}
    table = _table(axis, t, temp, y)
    assert {w["name"] for w in table["warnings"]} == {"not identifiable"}
    assert table["warnings"][0]["text"].startswith(
        "every coefficient is smaller than its standard error")
    # a VIF of thousands names it too, with the term
    axis["metrics"]["vif"] = {"T01": 83000.0}
    texts = [w["text"] for w in _table(axis, t, temp, y)["warnings"]]
    assert any(x.startswith("VIF up to 83,000 (T01") for x in texts)


def test_a_ridge_has_no_standard_errors_or_vif_but_its_dof_and_fold_spread():
    rng = np.random.default_rng(5)
    t = np.arange(600) * 60.0
    temp = 20 + 5 * np.sin(t / 4000.0)
    y = 2.0 * temp + rng.normal(0, 0.1, t.size)
    axis = {"intercept": -40.0, "fit": {"family": "ridge", "alpha": 1e-4},
            "terms": [{"kind": "temp", "source": "T01", "coef": 2.0}],
            "metrics": {"vif": {"T01": 1.0}, "condition_number": 1.0}}
    table = _table(axis, t, temp, y)
    assert not table["least_squares"] and table["max_vif"] is None
    assert all(math.isnan(r["se"]) and r["vif"] is None for r in table["rows"])
    assert "(±" not in table["equation"]
    assert 1.0 < table["effective_dof"] <= 2.0
    (gain,) = table["sensors"]
    assert table["folds"]["count"] == 3  # three time blocks of the one run
    assert gain["fold_steady_um_per_k"] == pytest.approx([2.0] * 3, abs=0.05)
    assert table["warnings"] == []
