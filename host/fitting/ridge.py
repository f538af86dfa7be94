"""Ridge least squares with its penalty chosen out of fold: shrinkage for the next day.

Select-then-accept (paper 000's subset, then effects one at a time) is high-variance on data
this small; a ridge over a fixed dynamic basis (the selected sensors, their first-order lags,
the spindle speed) shrinks what the folds cannot pin down instead of dropping it. The penalty
``alpha`` is per scaled column and per sample, so one grid serves every data size; the
intercept is free (never penalised).

Columns in one unit share one scale (``shared``: the temperatures, lags and rates, all in
kelvin): the penalty then weighs every micrometre per kelvin alike. Scaled each by its own
spread, a slow lag that barely moves in the training run was cheap to give a coefficient of
tens of um/K, and it extrapolates on a day that heats differently; in kelvin the ridge was
lower on every source on unseen runs (docs/next-day.md). Other columns (speed, squares) are
scaled by their own spread.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

ALPHA_GRID = tuple(float(a) for a in np.logspace(-5, 1, 13))  # 1e-5 .. 10


@dataclass(frozen=True)
class RidgeFit:
    coef: np.ndarray
    intercept: float
    alpha: float
    validation_rmse_um: float  # out of fold, at the chosen alpha
    fold_rmse_um: tuple[float, ...]

    def predict(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        return X @ self.coef + self.intercept if X.shape[1] else np.full(len(X), self.intercept)


def _solve(M: np.ndarray, v: np.ndarray, penalty: float) -> np.ndarray:
    """Ridge normal equations with an unpenalised intercept (row/column 0)."""
    P = np.eye(M.shape[0]) * penalty
    P[0, 0] = 0.0
    try:
        return np.linalg.solve(M + P, v)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(M + P, v, rcond=None)[0]


def column_scale(X: np.ndarray, shared: Sequence[bool] | None = None) -> np.ndarray:
    """Each column's scale: its own standard deviation, or for the ``shared`` columns (one
    unit) the root mean square of theirs, so their coefficients are penalised alike."""
    sd = X.std(axis=0) if X.shape[1] else np.zeros(0)
    if shared is not None:
        mask = np.asarray(shared, dtype=bool)
        if mask.shape != sd.shape:
            raise ValueError(f"shared: {mask.size} flags for {sd.size} columns")
        if mask.any():
            sd[mask] = np.sqrt(np.mean(sd[mask] ** 2))
    sd[sd == 0] = 1.0
    return sd


def fit_ridge(X: np.ndarray, y: np.ndarray, groups: np.ndarray,
              alphas: tuple[float, ...] = ALPHA_GRID,
              shared: Sequence[bool] | None = None) -> RidgeFit:
    """Ridge of ``y`` on ``X`` with ``alpha`` minimising the out-of-fold RMSE over ``groups``;
    the columns flagged in ``shared`` share one scale (column_scale).

    Ties go to the larger alpha (more shrinkage for the same held-out error).
    """
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    n, p = X.shape
    mean = X.mean(axis=0) if p else np.zeros(0)
    sd = column_scale(X, shared)
    D = np.empty((n, p + 1))
    D[:, 0] = 1.0
    if p:
        D[:, 1:] = (X - mean) / sd
    ids = np.unique(groups)
    rows = [groups == g for g in ids]
    M_f = np.array([D[r].T @ D[r] for r in rows])
    v_f = np.array([D[r].T @ y[r] for r in rows])
    s_f = np.array([float(y[r] @ y[r]) for r in rows])
    M, v = M_f.sum(axis=0), v_f.sum(axis=0)
    best: tuple[float, float, np.ndarray] | None = None
    for alpha in sorted(alphas, reverse=True):
        sse = np.empty(len(ids))
        for i, r in enumerate(rows):
            n_train = n - int(r.sum())
            b = _solve(M - M_f[i], v - v_f[i], alpha * n_train)
            sse[i] = max(float(s_f[i] - 2 * b @ v_f[i] + b @ M_f[i] @ b), 0.0)
        total = float(sse.sum())
        if best is None or total < best[0] * (1 - 1e-9):
            best = (total, alpha, sse)
    assert best is not None
    total, alpha, sse = best
    b = _solve(M, v, alpha * n)
    coef = b[1:] / sd
    intercept = float(b[0] - (mean / sd) @ b[1:]) if p else float(b[0])
    fold = tuple(float(np.sqrt(s / max(int(r.sum()), 1))) for s, r in zip(sse, rows, strict=True))
    return RidgeFit(coef, intercept, alpha, float(np.sqrt(total / n)), fold)
