"""Direct references for the out-of-fold engine (host.fitting.FoldGram): every fold refitted on
its raw rows, so tests compare the Gram-matrix shortcuts with the fits they stand for."""

from __future__ import annotations

import numpy as np

from thermal_comp.host.fitting import fit_linear, rmse


def direct_out_of_fold_residual(X: np.ndarray, y: np.ndarray, groups: np.ndarray
                                ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Residual of every row under the fit without its group, and each fold fit's coefficients."""
    residual = np.empty_like(y, dtype=float)
    coefs = []
    for g in np.unique(groups):
        test = groups == g
        fit = fit_linear(X[~test], y[~test])
        residual[test] = y[test] - fit.predict(X[test])
        coefs.append(fit.coef)
    return residual, coefs


def direct_validation_rmse(X: np.ndarray, y: np.ndarray, groups: np.ndarray) -> float:
    """RMSE of all out-of-fold predictions, each fold refitted on the other folds' rows."""
    return rmse(direct_out_of_fold_residual(X, y, groups)[0])


def direct_lag(x: np.ndarray, alpha: float) -> np.ndarray:
    """First-order lag written out as a loop (y[0] = x[0], y[n] = y[n-1] + alpha (x[n] -
    y[n-1])), independent of host.fitting's lfilter."""
    y = np.empty_like(np.asarray(x, dtype=float))
    y[0] = x[0]
    for n in range(1, len(x)):
        y[n] = y[n - 1] + alpha * (x[n] - y[n - 1])
    return y
