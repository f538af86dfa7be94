"""The ranking bench's numbers (docs/selection.md) rest on its Gram-matrix subset errors and its
rank correlation: both checked here against direct fits and scipy."""

from itertools import combinations

import numpy as np
from direct_fits import direct_validation_rmse
from scipy.stats import spearmanr

from bench.bench_ranking import SIZES, spearman, subset_errors
from thermal_comp.host.fitting import fit_linear, rmse


def test_subset_errors_equal_direct_fits():
    rng = np.random.default_rng(3)
    n, k = 300, 6
    X = 25 + np.cumsum(rng.normal(size=(n, k)), axis=0)  # drifting, correlated temperatures
    y = X @ rng.normal(size=k) + rng.normal(scale=0.5, size=n)
    Xt = X[-80:] + 3.0  # an unseen, hotter run
    yt = Xt @ rng.normal(size=k) * 0.1 + y[-80:]
    folds = np.repeat([0, 1, 2], n // 3)
    subsets, oof, train, test = subset_errors(X, y, folds, Xt, yt)
    assert subsets == [c for s in SIZES for c in combinations(range(k), s)]
    for i in (0, 7, len(subsets) - 1):
        cols = list(subsets[i])
        fit = fit_linear(X[:, cols], y)
        np.testing.assert_allclose(train[i], rmse(y - fit.predict(X[:, cols])), rtol=1e-8)
        np.testing.assert_allclose(test[i], rmse(yt - fit.predict(Xt[:, cols])), rtol=1e-8)
        np.testing.assert_allclose(oof[i], direct_validation_rmse(X[:, cols], y, folds),
                                   rtol=1e-8)


def test_rank_correlation_equals_scipy():
    rng = np.random.default_rng(0)
    a = rng.normal(size=200)
    b = a + rng.normal(size=200)
    np.testing.assert_allclose(spearman(a, b), spearmanr(a, b)[0], rtol=1e-12)
    assert spearman(a, -a) == -1.0
