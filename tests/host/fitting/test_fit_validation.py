"""Least squares, collinearity diagnostics and out-of-fold validation on known answers."""

from __future__ import annotations

import numpy as np

from thermal_comp.host.fitting import (
    condition_number,
    fit_linear,
    fold_groups,
    out_of_fold_predictions,
    penalty_groups,
    validation_rmse,
    variance_inflation,
)
from thermal_comp.host.io import Run


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


def _test_run(temps: np.ndarray, rpm: np.ndarray | None = None) -> Run:
    n = len(temps)
    t = np.arange(n) * 60.0
    aux = ([], None) if rpm is None else (["spindle_rpm"], rpm[:, None])
    return Run("r.csv", t, ["T1"], temps[:, None], ["d"], np.zeros((n, 1)), *aux)


def test_blocks_of_one_run_are_cut_where_its_heat_cool_phases_change():
    # 10 h at 1 min: spindle on for the first 6 h, off for the last 4 (heat, then cool)
    n = 600
    rpm = np.where(np.arange(n) < 360, 6000.0, 0.0)
    temps = 20 + np.minimum(np.arange(n), 360) * 0.01

    def cuts(run: Run) -> list[int]:
        return (np.flatnonzero(np.diff(fold_groups([run], 3, phases=True)[0])) + 1).tolist()

    # the equal split starts blocks at 200 and 400; the second cut moves to the spindle stop
    # (40 samples away, within a quarter block), the first has no transition near it
    assert cuts(_test_run(temps, rpm)) == [200, 360]
    assert "cut at its heat/cool transitions" in fold_groups([_test_run(temps, rpm)], 3,
                                                            phases=True)[1]
    # without phases (the effect search, the fit's validation): the equal split
    assert (np.flatnonzero(np.diff(fold_groups([_test_run(temps, rpm)], 3)[0])) + 1).tolist() \
        == [200, 400]
    # a speed step while the spindle runs is not a start or stop
    stepped = np.where(np.arange(n) < 210, 6000.0, np.where(np.arange(n) < 360, 3000.0, 0.0))
    assert cuts(_test_run(temps, stepped)) == [200, 360]
    # no aux input: the mean temperature's turn (heating to cooling at 360) is the transition
    rise_fall = 20 + 5 * np.sin(np.pi * np.arange(n) / 720)
    got = cuts(_test_run(rise_fall))
    assert got[0] == 200 and abs(got[1] - 360) <= 2
    # sensor noise on a steady run is no phase: the equal split
    noisy = 20 + 0.05 * np.random.default_rng(3).standard_normal(n)
    assert cuts(_test_run(noisy)) == [200, 400]
    # a transition farther than a quarter block from every cut leaves the equal split
    late = np.where(np.arange(n) < 500, 6000.0, 0.0)
    groups, scheme = fold_groups([_test_run(temps, late)], 3, phases=True)
    assert (np.flatnonzero(np.diff(groups)) + 1).tolist() == [200, 400]
    assert "heat/cool" not in scheme


def test_several_runs_are_left_out_one_at_a_time():
    groups, scheme = fold_groups([_run(3), _run(2)])
    assert "leave-one-run-out" in scheme and list(groups) == [0, 0, 0, 1, 1]


def test_the_penalty_of_two_days_is_chosen_on_each_days_blocks():
    # two runs: leave-one-run-out would fit each fold on one day, so each run's thirds are folds
    groups, scheme = penalty_groups([_run(6), _run(3)], n_blocks=3)
    assert list(groups) == [0, 0, 1, 1, 2, 2, 3, 4, 5]
    assert "each of the 2 runs" in scheme


def test_the_penalty_keeps_leave_one_run_out_otherwise():
    three = [_run(2), _run(2), _run(2)]
    assert list(penalty_groups(three)[0]) == list(fold_groups(three)[0]) == [0, 0, 1, 1, 2, 2]
    one = [_run(9)]
    assert list(penalty_groups(one)[0]) == list(fold_groups(one)[0])
    # two pieces of one run (a nested fold around a held-out block) are one day, not two
    whole = _run(12)
    pieces = [whole.slice(0, 4), whole.slice(8, 12)]
    assert all(p.piece for p in pieces) and not whole.piece and whole.slice(0, 4).every(2).piece
    assert list(penalty_groups(pieces)[0]) == [0, 0, 0, 0, 1, 1, 1, 1]


def test_out_of_fold_prediction_never_sees_its_own_group():
    # y depends on x differently in group 1: a model that saw group 1 would fit it
    x = np.arange(20, dtype=float)[:, None]
    groups = np.repeat([0, 1], 10)
    y = np.where(groups == 0, 2 * x[:, 0], 2 * x[:, 0] + 5)
    pred = out_of_fold_predictions(x, y, groups)
    # group 1 predicted from group 0's relation only: exactly 2x, off by 5
    np.testing.assert_allclose(pred[groups == 1], 2 * x[groups == 1, 0])
    assert abs(validation_rmse(x, y, groups) - 5.0) < 1e-9
