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
lower on every source on unseen runs (docs/training.md). Other columns (speed, squares) are
scaled by their own spread.

A bending axis (a column bent by its front against its back) hardly moves when the structure
warms evenly, though each of its sensors moves it by tens of um/K. ``even`` flags the columns
whose coefficients sum to that response (temperatures and lags, not rates: a rate settles to
zero), and ``even_penalty`` (kappa) penalises the square of the sum kappa times as much as one
coefficient's: the ridge then gives the front and the back large coefficients of opposite sign
rather than shrinking both toward the common warming (docs/training.md).

The coefficients may be fitted to the rows prefiltered (``fit_on``, host.fitting.prefilter)
while the out-of-fold error that picks the penalty is scored on the raw rows the box will see.
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


def _solve(M: np.ndarray, v: np.ndarray, penalty: float,
           shape: np.ndarray | None = None) -> np.ndarray:
    """Ridge normal equations with an unpenalised intercept (row/column 0); ``shape`` is the
    penalty's matrix over the scaled coefficients (the identity when None)."""
    P = (np.eye(M.shape[0]) if shape is None else shape) * penalty
    P[0, :] = 0.0
    P[:, 0] = 0.0
    try:
        return np.linalg.solve(M + P, v)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(M + P, v, rcond=None)[0]


def _design(X: np.ndarray, mean: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """The intercept's column of ones beside the scaled columns."""
    D = np.empty((len(X), X.shape[1] + 1))
    D[:, 0] = 1.0
    if X.shape[1]:  # in place: the same numbers without two temporaries the size of X
        np.subtract(X, mean, out=D[:, 1:])
        D[:, 1:] /= sd
    return D


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


def penalty_shape(p: int, even: Sequence[bool] | None, even_penalty: float
                  ) -> np.ndarray | None:
    """The penalty's matrix over the intercept and ``p`` scaled coefficients: the identity
    plus ``even_penalty`` times the square of the ``even`` columns' sum (None: the identity)."""
    if even is None or even_penalty == 0.0:
        return None
    flags = np.asarray(even, dtype=bool)
    if flags.shape != (p,):
        raise ValueError(f"even: {flags.size} flags for {p} columns")
    s = np.concatenate([[0.0], flags.astype(float)])
    return np.eye(p + 1) + even_penalty * np.outer(s, s)


def fit_ridge(X: np.ndarray, y: np.ndarray, groups: np.ndarray,
              alphas: tuple[float, ...] = ALPHA_GRID,
              shared: Sequence[bool] | None = None,
              even: Sequence[bool] | None = None, even_penalty: float = 0.0,
              fit_on: tuple[np.ndarray, np.ndarray] | None = None) -> RidgeFit:
    """Ridge of ``y`` on ``X`` with ``alpha`` minimising the out-of-fold RMSE over ``groups``;
    the columns flagged in ``shared`` share one scale (column_scale). ``even``: the columns
    whose coefficients' sum is penalised ``even_penalty`` times more (a bending axis; they
    must be ``shared``, so the sum is in one unit). ``fit_on``: the rows (X, y) the
    coefficients are fitted to, when not ``X``, ``y`` themselves (the same rows prefiltered,
    host.fitting.prefilter); the out-of-fold error is still scored on ``X``, ``y``.

    Ties go to the larger alpha (more shrinkage for the same held-out error).
    """
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    Xf, yf = (X, y) if fit_on is None else (np.asarray(fit_on[0], dtype=float),
                                            np.asarray(fit_on[1], dtype=float))
    if Xf.shape != X.shape or yf.shape != y.shape:
        raise ValueError(f"fit_on: rows of shape {Xf.shape} for {X.shape}")
    n, p = X.shape
    mean = Xf.mean(axis=0) if p else np.zeros(0)
    sd = column_scale(Xf, shared)
    shape = penalty_shape(p, even, even_penalty)
    if shape is not None and (shared is None or any(
            e and not s for e, s in zip(even, shared, strict=True))):
        raise ValueError("even: every column of the even-warming sum must be shared (one unit)")
    ids = np.unique(groups)
    rows = [groups == g for g in ids]
    D = _design(X, mean, sd)
    M_s = np.array([D[r].T @ D[r] for r in rows])  # the scored rows' normal equations
    v_s = np.array([D[r].T @ y[r] for r in rows])
    s_s = np.array([float(y[r] @ y[r]) for r in rows])
    if fit_on is None:
        M_f, v_f = M_s, v_s
    else:
        Df = _design(Xf, mean, sd)
        M_f = np.array([Df[r].T @ Df[r] for r in rows])
        v_f = np.array([Df[r].T @ yf[r] for r in rows])
    M, v = M_f.sum(axis=0), v_f.sum(axis=0)
    best: tuple[float, float, np.ndarray] | None = None
    for alpha in sorted(alphas, reverse=True):
        sse = np.empty(len(ids))
        for i, r in enumerate(rows):
            n_train = n - int(r.sum())
            b = _solve(M - M_f[i], v - v_f[i], alpha * n_train, shape)
            sse[i] = max(float(s_s[i] - 2 * b @ v_s[i] + b @ M_s[i] @ b), 0.0)
        total = float(sse.sum())
        if best is None or total < best[0] * (1 - 1e-9):
            best = (total, alpha, sse)
    assert best is not None
    total, alpha, sse = best
    b = _solve(M, v, alpha * n, shape)
    coef = b[1:] / sd
    intercept = float(b[0] - (mean / sd) @ b[1:]) if p else float(b[0])
    fold = tuple(float(np.sqrt(s / max(int(r.sum()), 1))) for s, r in zip(sse, rows, strict=True))
    return RidgeFit(coef, intercept, alpha, float(np.sqrt(total / n)), fold)
