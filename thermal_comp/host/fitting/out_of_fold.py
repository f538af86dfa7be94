"""The out-of-fold least-squares engine: fits of any column subset from per-fold Gram matrices.

Selection tries thousands of sensor subsets and the effect search hundreds of candidate
columns, each scored by refitting without every fold and predicting it. Refitting the raw
data for each would cost a pass over all rows per subset and fold; here the columns are
standardised once (global mean and SD, so the small systems stay well conditioned), an
intercept column keeps every fit's offset free, and each fold's Gram matrix ``D_f' D_f``, its
``D_f' y`` and ``y_f' y_f`` are summed once. A fit without fold f is then the normal equations
of (all - f) on the chosen rows and columns, and its squared error on fold f follows from
fold f's own Gram matrix; no subset touches the rows again.

One model is judged by refitting instead: ``validation_rmse`` and ``out_of_fold_predictions``
(training, the channel budget) fit each fold on its own training rows, centred there, as a
direct fit does (``FoldGram.refit_residual``). A column constant on a fold's training rows (a
speed input over runs whose spindle never changed speed) then gets no weight, where the
minimum-norm normal equations give it a share of the intercept that moves the held-out
prediction; and the normal equations square the condition number, which ranking subsets
tolerates better than a reported error does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from thermal_comp.host.fitting.linear import fit_linear, rmse

# A solution of the normal equations is trusted when M @ beta reproduces v to this fraction of
# v's largest entry (or absolutely, below 1); otherwise the system is singular or nearly so
# (duplicate or constant columns) and the minimum-norm least-squares solution is used.
SOLVE_TOLERANCE = 1e-8


def solve_normal(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Solve M @ beta = v: one system, several right-hand sides (v of shape (m, k)), or a batch
    if M is (F, m, m) and v (F, m). A singular system (duplicate or constant columns) falls
    back to minimum-norm least squares (the whole batch, if one of it is singular)."""
    vector = v.ndim == M.ndim - 1
    rhs = v[..., None] if vector else v
    try:
        beta = np.linalg.solve(M, rhs)
        residual = np.abs(M @ beta - rhs).max()
        if np.isfinite(residual) and residual <= SOLVE_TOLERANCE * max(1.0, float(np.abs(v).max())):
            return beta[..., 0] if vector else beta
    except np.linalg.LinAlgError:
        pass
    if M.ndim == 2:
        return np.linalg.lstsq(M, v, rcond=None)[0]
    return np.array([np.linalg.lstsq(m, b, rcond=None)[0] for m, b in zip(M, v, strict=True)])


def solve_many(M: np.ndarray, v: np.ndarray) -> list[np.ndarray]:
    """``[solve_normal(m, b) for m, b in zip(M, v)]`` in one stacked
    ``np.linalg.solve``: M is (K, ..., m, m) and v (K, ..., m) (a vector each) or
    (K, m, r) (r right-hand sides). Each request K is checked as solve_normal checks it, and
    one that is singular or fails the check is solved again by solve_normal itself (falling
    back to least squares as it does), so the result is solve_normal's, bit for bit."""
    K = M.shape[0]
    vector = v.ndim == M.ndim - 1
    rhs = v[..., None] if vector else v
    try:
        beta = np.linalg.solve(M, rhs)
    except np.linalg.LinAlgError:  # one of the stack is singular: each on its own
        return [solve_normal(M[k], v[k]) for k in range(K)]
    err = np.abs(M @ beta - rhs).reshape(K, -1).max(axis=1)
    tol = SOLVE_TOLERANCE * np.maximum(1.0, np.abs(v).reshape(K, -1).max(axis=1))
    out = list(beta[..., 0] if vector else beta)
    for k in np.flatnonzero(~(np.isfinite(err) & (err <= tol))).tolist():
        out[k] = solve_normal(M[k], v[k])
    return out


def _column_sd(X: np.ndarray, width: int = 128) -> np.ndarray:
    """``X.std(axis=0)`` of a row-major block, ``width`` columns at a time: the SD's
    temporary is a slice's size, not X's (70 MB for the effect search's thousand columns).
    Each column is reduced row by row either way, so the numbers are the same (a last block
    of one column, which numpy would sum pairwise, joins the one before)."""
    p = X.shape[1]
    starts = list(range(0, p, width)) or [0]
    if len(starts) > 1 and p - starts[-1] < 2:
        starts.pop()
    out = np.empty(p)
    for a, b in zip(starts, [*starts[1:], p], strict=True):
        out[a:b] = X[:, a:b].std(axis=0)
    return out


def _rows(a: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``a[mask]``; a view when the rows are one contiguous block (a fold is a run or a time
    block of one), which BLAS reads as it reads the copy."""
    at = np.flatnonzero(mask)
    if at.size and at[-1] - at[0] + 1 == at.size:
        return a[at[0]:at[-1] + 1]
    return a[mask]


class FoldGram:
    """Out-of-fold and training least squares of any subset of the columns of X, plus intercept.

    Column subsets are given as indices into X; the coefficients (``beta``, ``fold_betas``)
    are for the design ``D`` = [1, standardised X[:, cols]] and fit ``y0`` = y - mean(y).
    A fold whose complement holds no rows cannot be predicted: its errors are NaN.
    """

    def __init__(self, X: np.ndarray, y: np.ndarray, folds: np.ndarray) -> None:
        X = np.asarray(X, dtype=float)
        n, p = X.shape
        sd = X.std(axis=0)  # of X as given: a reduction's order follows its memory layout
        D = np.empty((n, p + 1))
        np.subtract(X, X.mean(axis=0), out=D[:, 1:])
        self._standardised(D, sd, y, folds)

    @classmethod
    def of_columns(cls, columns: Sequence[np.ndarray], y: np.ndarray, folds: np.ndarray
                   ) -> FoldGram:
        """``cls(np.column_stack(columns), y, folds)`` without that matrix: the columns go
        straight into the design (one rows x columns array less at the peak; the same numbers:
        the means and SDs of a row-major block are reduced row by row, in place or not)."""
        D = np.empty((len(y), len(columns) + 1))
        for j, column in enumerate(columns):
            D[:, j + 1] = column
        X = D[:, 1:]
        sd = _column_sd(X)
        X -= X.mean(axis=0)
        gram = cls.__new__(cls)
        gram._standardised(D, sd, y, folds)
        return gram

    def _standardised(self, D: np.ndarray, sd: np.ndarray, y: np.ndarray, folds: np.ndarray
                      ) -> None:
        """Set up from ``D`` holding the centred columns after its first and their SDs (scaled
        in place, the intercept column set)."""
        y = np.asarray(y, dtype=float)
        n, p = D.shape[0], D.shape[1] - 1
        sd[sd == 0] = 1.0
        D[:, 1:] /= sd
        D[:, 0] = 1.0
        self.D = D
        self.y0 = y - y.mean()
        self.n = n
        self.folds = np.asarray(folds)
        self.fold_ids = np.unique(self.folds)
        self.rows = [self.folds == g for g in self.fold_ids]
        self.n_f = np.array([int(r.sum()) for r in self.rows])
        F = len(self.fold_ids)
        self.M_f = np.empty((F, p + 1, p + 1))
        self.v_f = np.empty((F, p + 1))
        self.s_f = np.empty(F)
        for i, r in enumerate(self.rows):
            Df, yf = _rows(self.D, r), _rows(self.y0, r)
            self.M_f[i] = Df.T @ Df
            self.v_f[i] = Df.T @ yf
            self.s_f[i] = float(yf @ yf)
        self.M = self.M_f.sum(axis=0)
        self.v = self.v_f.sum(axis=0)
        self.s = float(self.s_f.sum())
        self._unpredictable = self.n_f == n  # no rows left to fit without this fold

    @staticmethod
    def index(cols: Sequence[int]) -> np.ndarray:
        """Positions of the intercept and of ``cols`` in the standardised design ``D``."""
        return np.array([0, *(int(c) + 1 for c in cols)], dtype=int)

    def beta(self, cols: Sequence[int]) -> np.ndarray:
        """Coefficients of the fit on all rows (intercept first)."""
        idx = self.index(cols)
        return solve_normal(self.M[idx[:, None], idx], self.v[idx])

    def train_rmse(self, cols: Sequence[int]) -> float:
        """RMSE (= residual SD, the intercept centres it) of the fit on all rows."""
        idx = self.index(cols)
        M, v = self.M[idx[:, None], idx], self.v[idx]
        beta = solve_normal(M, v)
        sse = self.s - 2 * beta @ v + beta @ M @ beta
        return math.sqrt(max(sse, 0.0) / self.n)

    def fold_betas(self, cols: Sequence[int]) -> np.ndarray:
        """(F, m) coefficients of the fit without each fold."""
        idx = self.index(cols)
        Mg = self.M_f[:, idx][:, :, idx]
        return solve_normal(self.M[idx[:, None], idx] - Mg, self.v[idx] - self.v_f[:, idx])

    def fold_sse(self, cols: Sequence[int], betas: np.ndarray | None = None) -> np.ndarray:
        """Squared error of each fold predicted by the fit without it (``betas`` if known)."""
        idx = self.index(cols)
        betas = self.fold_betas(cols) if betas is None else betas
        Mg = self.M_f[:, idx][:, :, idx]
        vg = self.v_f[:, idx]
        sse = (self.s_f - 2 * np.einsum("fi,fi->f", betas, vg)
               + np.einsum("fi,fij,fj->f", betas, Mg, betas))
        return np.where(self._unpredictable, np.nan, np.maximum(sse, 0.0))

    def validation_rmses(self, subsets: Sequence[Sequence[int]]) -> list[float]:
        """``[validation_rmse(cols) for cols in subsets]``, the fits without each fold of all
        subsets of one size solved in one stacked call (``solve_many``: the same numbers)."""
        out: list[float] = [math.nan] * len(subsets)
        by_size: dict[int, list[int]] = {}
        for k, cols in enumerate(subsets):
            by_size.setdefault(len(cols), []).append(k)
        for size, ks in by_size.items():
            idx = np.array([self.index(subsets[k]) for k in ks], dtype=int).reshape(
                len(ks), size + 1)
            rows, cols_ = idx[:, :, None], idx[:, None, :]
            Mg = np.moveaxis(self.M_f[:, rows, cols_], 0, 1)  # (K, F, m, m)
            vg = np.moveaxis(self.v_f[:, idx], 0, 1)  # (K, F, m)
            betas = solve_many(self.M[rows, cols_][:, None] - Mg, self.v[idx][:, None, :] - vg)
            for j, k in enumerate(ks):
                out[k] = self.validation_rmse(subsets[k], betas[j])
        return out

    def validation_rmse(self, cols: Sequence[int], betas: np.ndarray | None = None) -> float:
        """RMSE of all out-of-fold predictions (each fold predicted by a fit without it)."""
        return math.sqrt(float(self.fold_sse(cols, betas).sum()) / self.n)

    def fold_rmse(self, cols: Sequence[int], betas: np.ndarray | None = None) -> np.ndarray:
        """Held-out RMSE of each fold."""
        return np.sqrt(self.fold_sse(cols, betas) / self.n_f)

    def residual(self, cols: Sequence[int], betas: np.ndarray | None = None) -> np.ndarray:
        """Out-of-fold residual of every row (y minus the prediction of the fit without it),
        from the Gram-matrix fits."""
        idx = self.index(cols)
        betas = self.fold_betas(cols) if betas is None else betas
        out = np.empty(self.n)
        for b, r, lost in zip(betas, self.rows, self._unpredictable, strict=True):
            out[r] = np.nan if lost else self.y0[r] - self.D[r][:, idx] @ b
        return out


    def refit_residual(self, cols: Sequence[int]) -> np.ndarray:
        """``residual`` with each fold's fit solved on its training rows (host.fitting.fit_linear:
        centred on those rows, minimum norm where rank deficient) instead of the normal
        equations: one accurate design rather than many fast ones. A column constant on a
        fold's training rows gets no weight, as in a direct fit."""
        idx = self.index(cols)[1:]
        out = np.empty(self.n)
        for r, lost in zip(self.rows, self._unpredictable, strict=True):
            if lost:
                out[r] = np.nan
                continue
            fit = fit_linear(self.D[~r][:, idx], self.y0[~r])
            out[r] = self.y0[r] - fit.predict(self.D[r][:, idx])
        return out


def out_of_fold_predictions(X: np.ndarray, y: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Prediction of every row by a model fitted without its group (``FoldGram.refit_residual``)."""
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    return y - FoldGram(X, y, groups).refit_residual(range(X.shape[1]))


def validation_rmse(X: np.ndarray, y: np.ndarray, groups: np.ndarray) -> float:
    """RMSE of all out-of-fold predictions together (every sample predicted once, unseen)."""
    X = np.asarray(X, dtype=float)
    return rmse(FoldGram(X, y, groups).refit_residual(range(X.shape[1])))
