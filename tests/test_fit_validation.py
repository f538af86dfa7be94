"""Least squares, collinearity diagnostics and out-of-fold validation on known answers."""

from __future__ import annotations

import numpy as np

from host.fitting import (
    condition_number,
    fit_linear,
    fold_groups,
    out_of_fold_predictions,
    validation_rmse,
    variance_inflation,
)
from host.io import Run


def test_fit_recovers_exact_linear_relation():
    rng = np.random.default_rng(1)
    X = rng.normal(25, 3, size=(200, 3))
    y = 1.5 + X @ np.array([2.0, -0.5, 0.25])
    fit = fit_linear(X, y)
    np.testing.assert_allclose(fit.coef, [2.0, -0.5, 0.25], atol=1e-10)
    assert abs(fit.intercept - 1.5) < 1e-8


def test_vif_and_condition_flag_collinear_columns():
    rng = np.random.default_rng(2)
    a = rng.normal(size=500)
    b = rng.normal(size=500)
    independent = np.column_stack([a, b])
    collinear = np.column_stack([a, a + 1e-3 * b])
    assert np.all(variance_inflation(independent) < 1.1)
    assert np.all(variance_inflation(collinear) > 1e5)
    assert condition_number(collinear) > 1e2 * condition_number(independent)


def _run(n: int) -> Run:
    t = np.arange(n, dtype=float)
    return Run("r.csv", t, ["T1"], t[:, None], ["d"], t[:, None])


def test_single_run_is_cut_into_contiguous_blocks():
    groups, scheme = fold_groups([_run(10)], n_blocks=3)
    assert "time-blocked" in scheme
    assert list(groups) == [0, 0, 0, 0, 1, 1, 1, 2, 2, 2]


def test_several_runs_are_left_out_one_at_a_time():
    groups, scheme = fold_groups([_run(3), _run(2)])
    assert "leave-one-run-out" in scheme and list(groups) == [0, 0, 0, 1, 1]


def test_out_of_fold_prediction_never_sees_its_own_group():
    # y depends on x differently in group 1: a model that saw group 1 would fit it
    x = np.arange(20, dtype=float)[:, None]
    groups = np.repeat([0, 1], 10)
    y = np.where(groups == 0, 2 * x[:, 0], 2 * x[:, 0] + 5)
    pred = out_of_fold_predictions(x, y, groups)
    # group 1 predicted from group 0's relation only: exactly 2x, off by 5
    np.testing.assert_allclose(pred[groups == 1], 2 * x[groups == 1, 0])
    assert abs(validation_rmse(x, y, groups) - 5.0) < 1e-9
