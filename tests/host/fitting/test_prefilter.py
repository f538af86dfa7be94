"""The ridge's prefilter (host.fitting.prefilter) and the ridge fitted to prefiltered rows
while scored on the raw ones (host.fitting.ridge.fit_ridge's ``fit_on``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sklearn.linear_model import Ridge

from thermal_comp.host.fitting import fit_ridge
from thermal_comp.host.fitting.prefilter import PREFILTER_TAU_S, prefiltered
from thermal_comp.host.io import Run
from thermal_comp.host.train import train_model


def _low_pass_by_hand(x: np.ndarray, lengths: list[int], a: float) -> np.ndarray:
    """y[k] = y[k-1] + a (x[k] - y[k-1]), y = x at each run's first sample."""
    out, start = np.empty(len(x)), 0
    for n in lengths:
        for k in range(start, start + n):
            out[k] = x[k] if k == start else out[k - 1] + a * (x[k] - out[k - 1])
        start += n
    return out


def test_each_run_is_low_passed_from_its_own_first_sample():
    rng = np.random.default_rng(0)
    lengths = [40, 25]
    X, y = rng.normal(size=(65, 3)), rng.normal(size=65)
    Xf, yf = prefiltered(X, y, lengths, period_s=60.0, tau_s=180.0)
    a = 1 - math.exp(-60.0 / 180.0)
    np.testing.assert_allclose(yf, _low_pass_by_hand(y, lengths, a), rtol=1e-12)
    for j in range(3):
        np.testing.assert_allclose(Xf[:, j], _low_pass_by_hand(X[:, j], lengths, a),
                                   rtol=1e-12)
    assert Xf[40, 0] == X[40, 0]  # the second run starts afresh
    steady, _ = prefiltered(np.full((10, 1), 21.5), np.zeros(10), [10], 60.0)
    np.testing.assert_array_equal(steady, 21.5)  # a steady start has no transient
    same = prefiltered(X, y, lengths, 60.0, tau_s=0.0)
    assert same[0] is X and same[1] is y
    with pytest.raises(ValueError, match="runs of 60 samples for 65 rows"):
        prefiltered(X, y, [40, 20], 60.0)


def test_the_filter_commutes_with_a_linear_model_and_takes_white_noise_out():
    """Coefficients fitted on filtered rows are the coefficients on the raw readings, and
    white noise keeps a / (2 - a) of its variance (a first-order filter's gain)."""
    rng = np.random.default_rng(1)
    X, b = rng.normal(size=(5000, 4)), np.array([1.5, -2.0, 0.3, 4.0])
    Xf, yf = prefiltered(X, X @ b + 7.0, [5000], period_s=15.0)
    np.testing.assert_allclose(yf, Xf @ b + 7.0, rtol=1e-10, atol=1e-10)
    a = 1 - math.exp(-15.0 / PREFILTER_TAU_S)
    assert np.var(Xf[100:], axis=0) == pytest.approx(np.full(4, a / (2 - a)), rel=0.15)


def _slow_and_noisy(seed: int):
    """Two slow temperatures (a heat-up and a wander), read with white noise, and a probe
    that sees 3 and -1.5 um/K of the true ones plus its own white noise."""
    rng = np.random.default_rng(seed)
    n = 2000
    t = np.arange(n) * 60.0
    true = np.column_stack([8 * (1 - np.exp(-t / 7200.0)),
                            2 * np.sin(t / 9000.0) + 0.001 * rng.normal(size=n).cumsum()])
    X = 20 + true + 0.4 * rng.normal(size=(n, 2))
    y = true @ [3.0, -1.5] + 0.5 * rng.normal(size=n)
    return X, y, np.repeat([0, 1, 2], [700, 700, 600])


def test_the_ridge_fits_the_prefiltered_rows_and_reports_the_raw_rows_error():
    """Against an independent computation: scikit-learn's ridge on the filtered rows (scaled
    as the filtered columns), its fold models scored on the raw rows."""
    X, y, groups = _slow_and_noisy(2)
    slow = prefiltered(X, y, [len(y)], period_s=60.0)
    alpha, n = 1e-3, len(y)
    fit = fit_ridge(X, y, groups, alphas=(alpha,), fit_on=slow)
    mu, sd = slow[0].mean(0), slow[0].std(0)
    ref = Ridge(alpha=alpha * n).fit((slow[0] - mu) / sd, slow[1])
    np.testing.assert_allclose(fit.coef, ref.coef_ / sd, rtol=1e-8)
    folds = []
    for g in range(3):
        out = groups == g
        m = Ridge(alpha=alpha * int((~out).sum())).fit((slow[0][~out] - mu) / sd, slow[1][~out])
        folds.append(math.sqrt(np.mean((m.predict((X[out] - mu) / sd) - y[out]) ** 2)))
    np.testing.assert_allclose(fit.fold_rmse_um, folds, rtol=1e-7)
    assert min(folds) > 0.5  # the raw rows' noise is in the score: the box sees it
    with pytest.raises(ValueError, match="fit_on: rows of shape"):
        fit_ridge(X, y, groups, fit_on=(slow[0][:-1], slow[1][:-1]))


def test_the_prefilter_pulls_the_coefficients_less_toward_zero_on_noisy_readings():
    """The thermocouples' white noise attenuates least-squares coefficients (errors in
    variables); on the slow drift the filter keeps, they come out nearer the truth."""
    for seed in (3, 4, 5):
        X, y, groups = _slow_and_noisy(seed)
        raw = fit_ridge(X, y, groups, alphas=(1e-9,))
        pre = fit_ridge(X, y, groups, alphas=(1e-9,),
                        fit_on=prefiltered(X, y, [len(y)], period_s=60.0, tau_s=600.0))
        truth = np.array([3.0, -1.5])
        assert np.abs(pre.coef - truth).max() < 0.5 * np.abs(raw.coef - truth).max()


def test_the_prefilter_is_a_training_option_recorded_and_checked(tmp_path):
    import json

    from thermal_comp.host.cli import main
    from thermal_comp.host.io import write_run
    from thermal_comp.host.train import TrainingError

    X, y, _ = _slow_and_noisy(7)
    t = np.arange(len(y)) * 60.0
    run = Run("a", t, ["T1", "T2"], X, ["dz_um"], y[:, None], [], np.zeros((len(y), 0)))
    kw = dict(effects=False, nested=False, groups=2, max_sensors=2)
    default = train_model([run], ["dz_um"], **kw)
    raw = train_model([run], ["dz_um"], prefilter_s=0.0, **kw)
    assert default["training"]["prefilter_s"] == PREFILTER_TAU_S
    assert default["axes"]["dz_um"]["fit"]["prefilter_tau_s"] == PREFILTER_TAU_S
    assert raw["training"]["prefilter_s"] == 0.0
    assert raw["axes"]["dz_um"]["fit"]["prefilter_tau_s"] == 0.0
    assert raw["axes"]["dz_um"]["terms"] != default["axes"]["dz_um"]["terms"]
    for bad in (-1.0, float("nan")):
        with pytest.raises(TrainingError, match="--prefilter-s must be 0 .off. or a time"):
            train_model([run], ["dz_um"], prefilter_s=bad, **kw)
    csv = tmp_path / "a.csv"
    write_run(csv, t, {"T1": X[:, 0], "T2": X[:, 1], "dz_um": y})
    assert main(["train", str(csv), "--target", "dz_um", "--no-nested", "--no-effects",
                 "--no-codegen", "--prefilter-s", "600", "--out", str(tmp_path / "m")]) == 0
    model = json.loads((tmp_path / "m" / "model.json").read_text())
    assert model["axes"]["dz_um"]["fit"]["prefilter_tau_s"] == 600.0


def test_an_axis_kept_as_least_squares_does_not_claim_the_prefilter(monkeypatch):
    """`--fit auto` may keep least squares, which fits the raw rows: the axis says 0."""
    import thermal_comp.host.train.nested as nested

    monkeypatch.setattr(nested.NestedResult, "rms",
                        lambda self, family: 0.0 if family == "ols" else 1.0)
    X, y, _ = _slow_and_noisy(8)
    t = np.arange(len(y)) * 60.0
    run = Run("a", t, ["T1", "T2"], X, ["dz_um"], y[:, None], [], np.zeros((len(y), 0)))
    model = train_model([run], ["dz_um"], effects=False, groups=2, max_sensors=2, fit="auto")
    fit = model["axes"]["dz_um"]["fit"]
    assert fit["family"] == "ols" and fit["prefilter_tau_s"] == 0.0
    assert model["training"]["prefilter_s"] == PREFILTER_TAU_S  # what was asked, on record
