"""Sequential selection, EC reduction and the Gram-matrix fits against independent answers."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from direct_fits import direct_validation_rmse

from thermal_comp.host.selection import (
    GramCache,
    ec_reduction,
    fold_labels,
    group_refinement,
    select_sensors,
    sequential_selection,
)
from thermal_comp.host.selection.estimator import ThermalSensorSelector


def _lstsq_rmse(X: np.ndarray, y: np.ndarray) -> float:
    A = np.column_stack([np.ones(len(y)), X])
    beta, *_ = np.linalg.lstsq(A, y, rcond=None)
    return float(np.sqrt(np.mean((y - A @ beta) ** 2)))


def test_gram_fits_equal_direct_least_squares():
    rng = np.random.default_rng(0)
    X = 25 + rng.normal(size=(500, 6)).cumsum(axis=0) * 0.1
    y = X @ rng.normal(size=6) + rng.normal(size=500)
    folds = fold_labels(np.zeros(500), 3)
    cache = GramCache(X, y, folds)
    for cols in ([0], [1, 4], [0, 2, 3, 5], list(range(6))):
        assert cache.train_rmse(cols) == pytest.approx(_lstsq_rmse(X[:, cols], y), rel=1e-9)
        assert cache.validation_rmse(cols) == pytest.approx(
            direct_validation_rmse(X[:, cols], y, folds), rel=1e-8)


def test_gram_fit_survives_duplicate_columns():
    rng = np.random.default_rng(1)
    a = rng.normal(size=200)
    X = np.column_stack([a, a, rng.normal(size=200)])
    y = 2 * a + 0.1 * rng.normal(size=200)
    cache = GramCache(X, y, np.zeros(200, dtype=int))
    assert cache.train_rmse([0, 1]) == pytest.approx(_lstsq_rmse(X[:, :1], y), rel=1e-6)


def test_sequential_selection_picks_the_member_with_smallest_error():
    rng = np.random.default_rng(2)
    n = 400
    a = rng.normal(size=n).cumsum()
    b = rng.normal(size=n).cumsum()
    y = a + 0.5 * b
    X = np.column_stack([
        a + 3.0 * rng.normal(size=n),  # group 1: noisy copy of a
        a + 0.1 * rng.normal(size=n),  # group 1: clean copy of a
        b + 2.0 * rng.normal(size=n),  # group 1: noisy copy of b
        rng.normal(size=n),            # group 0: unrelated (smallest group, goes first)
        b + 0.2 * rng.normal(size=n),  # group 2: clean b
        b + 1.0 * rng.normal(size=n),  # group 2
    ])
    labels = np.array([1, 1, 1, 0, 2, 2])
    cache = GramCache(X, y, np.zeros(n, dtype=int))
    reps, steps = sequential_selection(cache, labels, "train")
    # independent: replay eq. 9 with numpy least squares
    expected: list[int] = []
    for g in range(3):
        members = np.flatnonzero(labels == g)
        errs = [_lstsq_rmse(X[:, [*expected, m]], y) for m in members]
        expected.append(int(members[int(np.argmin(errs))]))
    assert reps == expected
    assert reps[1] == 1 and reps[2] == 4  # the clean copies win
    assert [s.group for s in steps] == [0, 1, 2]


class _FixedErrors:
    """A stand-in for GramCache whose error depends only on the subset (constructed curve)."""

    def __init__(self, table: dict[tuple[int, ...], float]) -> None:
        self.table = table

    def error(self, cols, kind):
        return self.table[tuple(cols)]

    def fold_rmse(self, cols):  # one fold: its error is the subset's
        return np.array([self.table[tuple(cols)]])


def test_ec_picks_argmin_of_constructed_curve():
    reps = [0, 1, 2, 3, 4]
    c = len(reps)
    rng = np.random.default_rng(3)
    table = {}
    for size in range(1, c + 1):
        for combo in itertools.combinations(reps, size):
            table[combo] = 10.0 / size ** 1.6 + rng.uniform(0.0, 0.2)
    best = [min(v for k, v in table.items() if len(k) == i) for i in range(1, c + 1)]
    ec_expected = [best[i - 1] / best[0] * i / c for i in range(1, c + 1)]
    result = ec_reduction(_FixedErrors(table), reps, "train", max_sensors=c)
    np.testing.assert_allclose(result.curve, ec_expected)
    assert result.chosen_count == int(np.argmin(ec_expected)) + 1
    chosen = result.subsets[result.chosen_count - 1]
    assert table[tuple(chosen)] == best[result.chosen_count - 1]


def test_ec_count_is_capped_by_max_sensors():
    reps = [0, 1, 2, 3]
    table = {combo: 1.0 / 10 ** len(combo) for size in range(1, 5)
             for combo in itertools.combinations(reps, size)}  # EC falls all the way
    assert ec_reduction(_FixedErrors(table), reps, "train", max_sensors=4).chosen_count == 4
    assert ec_reduction(_FixedErrors(table), reps, "train", max_sensors=2).chosen_count == 2


def test_min_rule_picks_smallest_error_not_ec():
    reps = [0, 1, 2]
    table = {(0,): 4.0, (1,): 5.0, (2,): 6.0, (0, 1): 3.0, (0, 2): 3.5, (1, 2): 3.8,
             (0, 1, 2): 2.9}
    # EC = [1/3, 0.5, 0.725]: EC keeps 1 sensor, the smallest error keeps all 3
    assert ec_reduction(_FixedErrors(table), reps, "validation", 5, "ec").chosen_count == 1
    assert ec_reduction(_FixedErrors(table), reps, "validation", 5, "min").chosen_count == 3


def _two_source_data(n: int = 1200, seed: int = 4):
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    fast = np.convolve(rng.normal(size=n + 30), np.ones(30) / 30, "valid")[:n].cumsum() * 0.05
    slow = np.sin(2 * np.pi * t / 900.0)
    temps = [fast + 0.02 * rng.normal(size=n) for _ in range(4)]
    temps += [slow + 0.02 * rng.normal(size=n) for _ in range(4)]
    X = np.column_stack(temps) + 25.0
    y = 3 * fast - 2 * slow + 0.05 * rng.normal(size=n)
    return X, y


@pytest.mark.parametrize("method", ["paper", "validated", "validated-refined", "validated-ec"])
def test_select_sensors_keeps_one_sensor_of_each_source(method):
    X, y = _two_source_data()
    n = len(y)
    result = select_sensors(X, y, np.zeros(n), fold_labels(np.zeros(n)), 60.0, n_groups=2,
                            max_sensors=5, method=method)
    assert len(result.sensors) == 2
    assert {s // 4 for s in result.sensors} == {0, 1}  # one from each source group


def test_selector_in_pipeline_and_cross_val_score():
    from sklearn.linear_model import LinearRegression
    from sklearn.model_selection import GroupKFold, cross_val_score
    from sklearn.pipeline import make_pipeline

    X, y = _two_source_data()
    pipe = make_pipeline(ThermalSensorSelector(n_groups=2, period_s=60.0), LinearRegression())
    groups = np.repeat([0, 1, 2], len(y) // 3)
    scores = cross_val_score(pipe, X, y, cv=GroupKFold(n_splits=3), groups=groups)
    assert np.all(scores > 0.9)
    sel = ThermalSensorSelector(n_groups=2, period_s=60.0).fit(X, y)
    assert sel.transform(X).shape == (len(y), int(sel.get_support().sum()))
    assert sel.correlations_.shape == (8,) and sel.delays_.shape == (8,)
    chosen = np.flatnonzero(sel.get_support())  # one sensor per group (refinement keeps that)
    assert len(set(sel.labels_[chosen])) == len(chosen)
    assert sel.labels_.shape == (8,) and len(sel.ec_curve_) == 2


def test_selector_rejects_bad_parameters():
    X, y = _two_source_data(100)
    with pytest.raises(ValueError, match="unknown selection method"):
        ThermalSensorSelector(selection="nope").fit(X, y)
    with pytest.raises(ValueError, match="max-sensors"):
        ThermalSensorSelector(max_sensors=0).fit(X, y)


def _greedy_trap(n: int = 900, p_noise: float = 0.6, seed: int = 7):
    """y = a + b. Group 0 holds P = a + 0.5 b + noise (best alone, so eq. 9 takes it first) and
    Q = a; group 1 holds B = b. Jointly {Q, B} explains y and {P, B} keeps P's noise."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=n).cumsum()
    b = rng.normal(size=n).cumsum()
    P = a + 0.5 * b + p_noise * rng.normal(size=n)
    Q = a + 0.05 * rng.normal(size=n)
    X = np.column_stack([P, Q, b]) + 25.0
    y = a + b + 0.05 * rng.normal(size=n)
    return X, y, np.array([0, 0, 1])


def _oof(X, y, folds, cols):
    return direct_validation_rmse(X[:, cols], y, folds)


def test_group_refinement_replaces_the_member_eq9_chose_too_early():
    X, y, labels = _greedy_trap()
    folds = fold_labels(np.zeros(len(y)), 3)
    cache = GramCache(X, y, folds)
    reps, _ = sequential_selection(cache, labels, "validation")
    assert reps == [0, 2]  # the trap: P wins its group alone
    before, after = _oof(X, y, folds, [0, 2]), _oof(X, y, folds, [1, 2])
    assert after < 0.5 * before  # independent out-of-fold fits: Q is the better partner
    chosen, swaps = group_refinement(cache, labels, reps, "validation")
    assert chosen == [1, 2]
    assert [(w.removed, w.added) for w in swaps] == [(0, 1)]
    assert swaps[0].error_before == pytest.approx(before, rel=1e-8)
    assert swaps[0].error_after == pytest.approx(after, rel=1e-8)


def test_group_refinement_needs_more_than_the_margin():
    X, y, labels = _greedy_trap()
    folds = fold_labels(np.zeros(len(y)), 3)
    cache = GramCache(X, y, folds)
    gain = 1 - _oof(X, y, folds, [1, 2]) / _oof(X, y, folds, [0, 2])
    assert group_refinement(cache, labels, [0, 2], "validation", margin=gain * 1.01)[1] == []
    assert group_refinement(cache, labels, [0, 2], "validation", margin=gain * 0.99)[0] == [1, 2]


def test_group_refinement_keeps_groups_count_and_never_raises_the_error():
    rng = np.random.default_rng(11)
    n, k = 600, 12
    X = 25 + rng.normal(size=(n, k)).cumsum(axis=0) * 0.1
    y = X[:, [1, 4, 7, 10]] @ np.array([1.0, -0.5, 0.8, 0.3]) + rng.normal(size=n) * 0.2
    labels = np.arange(k) % 4
    folds = fold_labels(np.zeros(n), 3)
    cache = GramCache(X, y, folds)
    start = [0, 5, 6, 11]  # one per group, deliberately poor
    chosen, swaps = group_refinement(cache, labels, start, "validation")
    assert [labels[c] for c in chosen] == [labels[c] for c in start]
    assert len(set(chosen)) == len(chosen)
    assert swaps  # the poor start leaves room
    assert _oof(X, y, folds, chosen) <= _oof(X, y, folds, start)
    # every remaining within-group swap is worth less than the 1 % margin
    err = _oof(X, y, folds, chosen)
    for pos, c in enumerate(chosen):
        for m in np.flatnonzero(labels == labels[c]):
            if m not in chosen:
                trial = [*chosen[:pos], int(m), *chosen[pos + 1:]]
                assert _oof(X, y, folds, trial) >= err * 0.99 - 1e-12


def test_only_validated_refined_refines_and_the_trace_says_so():
    X, y = _two_source_data()
    n = len(y)
    folds = fold_labels(np.zeros(n))
    names = [f"T{i:02d}" for i in range(X.shape[1])]
    for method, refines in (("validated-refined", True), ("validated", False),
                            ("validated-ec", False), ("paper", False)):
        result = select_sensors(X, y, np.zeros(n), folds, 60.0, n_groups=3, method=method)
        trace = result.trace(names)
        assert ("refinement" in trace) is refines
        if not refines:
            assert result.sensors == result.ec.subsets[result.ec.chosen_count - 1]


def test_the_ec_trace_keeps_each_size_fold_errors_for_the_error_bars():
    """Each out-of-fold S_i comes with the held-out RMSE of every fold (the report's EC
    error bars): recomputed here by numpy least squares without each fold."""
    X, y = _two_source_data()
    n = len(y)
    folds = fold_labels(np.zeros(n))
    names = [f"T{i:02d}" for i in range(X.shape[1])]
    trace = select_sensors(X, y, np.zeros(n), folds, 60.0, n_groups=3).trace(names)
    per_fold = trace["ec_fold_errors_um"]
    assert len(per_fold) == len(trace["ec_errors_um"])
    for subset, s_i, fold_rmse in zip(trace["ec_subsets"], trace["ec_errors_um"], per_fold,
                                      strict=True):
        cols = [names.index(s) for s in subset]
        want = []
        for f in np.unique(folds):
            tr, te = folds != f, folds == f
            A = np.column_stack([np.ones(tr.sum()), X[tr][:, cols]])
            beta = np.linalg.lstsq(A, y[tr], rcond=None)[0]
            pred = beta[0] + X[te][:, cols] @ beta[1:]
            want.append(np.sqrt(np.mean((y[te] - pred) ** 2)))
        np.testing.assert_allclose(fold_rmse, want, rtol=1e-6)
        assert min(fold_rmse) - 1e-12 <= s_i <= max(fold_rmse) + 1e-12
    paper = select_sensors(X, y, np.zeros(n), folds, 60.0, n_groups=3, method="paper")
    assert "ec_fold_errors_um" not in paper.trace(names)  # a training error has no folds
