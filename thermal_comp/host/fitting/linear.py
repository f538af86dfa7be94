"""Least-squares fit of a linear thermal model and the diagnostics that justify it.

Paper 000, eq. 4: delta(t) = C0 + sum_i Ci * x_i(t). The fit centres the columns first
(numerically kinder than appending a column of ones when temperatures sit near 25 degC) and
reports the collinearity diagnostics (condition number, VIF) that the selection method exists
to keep small.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class LinearFit:
    coef: np.ndarray  # (k,)
    intercept: float

    def predict(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        if X.shape[1] == 0:
            return np.full(X.shape[0], self.intercept)
        return X @ self.coef + self.intercept


def fit_linear(X: np.ndarray, y: np.ndarray) -> LinearFit:
    """Ordinary least squares with intercept; rank-deficient columns get minimum-norm weights."""
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    y_mean = float(y.mean())
    if X.shape[1] == 0:
        return LinearFit(np.zeros(0), y_mean)
    x_mean = X.mean(axis=0)
    coef, *_ = np.linalg.lstsq(X - x_mean, y - y_mean, rcond=None)
    return LinearFit(coef, float(y_mean - x_mean @ coef))


def rmse(residual: np.ndarray) -> float:
    residual = np.asarray(residual, dtype=float)
    return float(np.sqrt(np.mean(residual ** 2))) if residual.size else float("nan")


def r_squared(y: np.ndarray, y_hat: np.ndarray) -> float:
    ss_res = float(np.sum((y - y_hat) ** 2))
    ss_tot = float(np.sum((y - np.mean(y)) ** 2))
    return 1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan")


def condition_number(X: np.ndarray) -> float:
    """Condition number of the standardised design (1 = orthogonal columns)."""
    X = np.asarray(X, dtype=float)
    if X.shape[1] == 0:
        return 1.0
    sd = X.std(axis=0)
    sd[sd == 0] = 1.0
    return float(np.linalg.cond((X - X.mean(axis=0)) / sd))


def variance_inflation(X: np.ndarray) -> np.ndarray:
    """VIF_j = 1 / (1 - R_j^2), R_j^2 from regressing column j on the others.

    That is the j-th diagonal element of the inverse correlation matrix: one p x p inverse
    instead of p regressions over every sample (the ridge's 25-column basis over a day at
    1 Hz took a second the other way). Constant or exactly dependent columns take the
    regressions, which say so (VIF 1 for a constant, inf for a dependent column).
    """
    X = np.asarray(X, dtype=float)
    k = X.shape[1]
    out = np.ones(k)
    if k < 2:
        return out
    sd = X.std(axis=0)
    if np.all(sd > 0):
        Z = (X - X.mean(axis=0)) / sd
        corr = Z.T @ Z / X.shape[0]
        if np.linalg.cond(corr) < 1e12:
            return np.diag(np.linalg.inv(corr)).copy()
    for j in range(k):
        others = np.delete(X, j, axis=1)
        fit = fit_linear(others, X[:, j])
        r2 = r_squared(X[:, j], fit.predict(others))
        out[j] = np.inf if r2 >= 1.0 else 1.0 / (1.0 - r2)
    return out
