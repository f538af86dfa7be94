"""The accuracy bench's peers: the scikit-learn methods ours is measured against, fitted on
the training runs only, scored on the test runs by the bench's one score, and each peer's own
out-of-fold error on the training file (the peer a user would pick without the test run)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from bench.accuracy_jobs import Job
from bench.accuracy_score import reference_window, referenced, score

LAG_TAUS_S = (600.0, 1800.0, 5400.0)  # first-order lags of every sensor for the lag peers
EXHAUSTIVE_LIMIT = 60_000  # subsets; C(25,5) = 53,130 runs, C(65,4) = 677,040 is skipped
HGB_MAX_ROWS = 2000  # gradient boosting fits on every k-th training row beyond this


def peer_features(run, reference: str, lags: bool) -> np.ndarray:
    """Temperatures (plus their first-order lags) of one run, referenced at its start."""
    from thermal_comp.host.fitting import first_order_lag

    X = run.temperatures
    parts = [X]
    if lags:
        for tau in LAG_TAUS_S:
            alpha = -math.expm1(-run.period_s / tau)
            parts.append(np.column_stack([first_order_lag(X[:, j], alpha)
                                          for j in range(X.shape[1])]))
    F = np.hstack(parts)
    return referenced(F, reference_window(run.period_s)) if reference == "start" else F


def peer_target(run, target: str, reference: str) -> np.ndarray:
    y = run.target(target)
    return referenced(y, reference_window(run.period_s)) if reference == "start" else y


Predictor = Callable[[np.ndarray], np.ndarray]


@dataclass
class PeerFit:
    """A fitted peer: its prediction from the features (None when skipped), whether it reads
    the lag features, the thermocouples it reads and a note."""

    predict: Predictor | None
    lags: bool = False
    n_sensors: int = 0
    note: str = ""


def fit_peers(X: np.ndarray, XL: np.ndarray, y: np.ndarray, folds: np.ndarray,
              exhaustive_limit: int = EXHAUSTIVE_LIMIT) -> dict[str, PeerFit]:
    """Every peer fitted on the training features (``XL``: the sensors, then their lags)."""
    from sklearn.ensemble import HistGradientBoostingRegressor
    from sklearn.feature_selection import SequentialFeatureSelector
    from sklearn.linear_model import LassoCV, LinearRegression, RidgeCV
    from sklearn.model_selection import PredefinedSplit
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from thermal_comp.host.analysis.compare import best_subset
    from thermal_comp.host.selection import pearson_r

    cv = PredefinedSplit(folds)
    n = X.shape[1]
    out: dict[str, PeerFit] = {}

    def ols(cols: Sequence[int], note: str = "") -> PeerFit:
        idx = [int(i) for i in cols]
        fit = LinearRegression().fit(X[:, idx], y)
        return PeerFit(lambda F: fit.predict(F[:, idx]), False, len(idx), note)

    def sensors_of(coef: np.ndarray) -> int:  # lag feature j belongs to sensor j % n
        return int(np.unique(np.flatnonzero(np.abs(coef) > 0) % n).size)

    out["OLS all"] = ols(range(n))
    order = np.argsort(-np.abs(pearson_r(X, y)), kind="stable")
    out["top-4 |r|"] = ols(order[:4])
    for k in (4, 5):
        if k >= n:
            out[f"SFS-{k}"] = out[f"best-{k}"] = PeerFit(None, note="skipped: k >= sensors")
            continue
        sfs = SequentialFeatureSelector(LinearRegression(), n_features_to_select=k,
                                        direction="forward", cv=cv,
                                        scoring="neg_root_mean_squared_error").fit(X, y)
        out[f"SFS-{k}"] = ols(np.flatnonzero(sfs.get_support()))
        subsets = math.comb(n, k)
        if subsets <= exhaustive_limit:
            out[f"best-{k}"] = ols(best_subset(X, y, k), f"{subsets} subsets")
        else:
            out[f"best-{k}"] = PeerFit(None, note=f"skipped: C({n},{k}) = {subsets} subsets")
    lasso = make_pipeline(StandardScaler(), LassoCV(cv=cv, max_iter=20000)).fit(X, y)
    out["LassoCV"] = PeerFit(lasso.predict, False, sensors_of(lasso[-1].coef_))
    ridge = make_pipeline(StandardScaler(), RidgeCV(alphas=np.logspace(-3, 4, 15), cv=cv)
                          ).fit(XL, y)
    out["ridge+lags"] = PeerFit(ridge.predict, True, n, f"alpha {ridge[-1].alpha_:.3g}")
    lasso_l = make_pipeline(StandardScaler(), LassoCV(cv=cv, max_iter=20000)).fit(XL, y)
    out["lasso+lags"] = PeerFit(lasso_l.predict, True, sensors_of(lasso_l[-1].coef_),
                                f"{int(np.count_nonzero(lasso_l[-1].coef_))} of {XL.shape[1]} "
                                "features")
    step = max(1, X.shape[0] // HGB_MAX_ROWS)  # smooth thermal data: thinning costs little
    hgb = HistGradientBoostingRegressor(random_state=0).fit(X[::step], y[::step])
    out["HGB"] = PeerFit(hgb.predict, False, n,
                         f"every {step}. training row" if step > 1 else "")
    return out


def inner_folds(groups: np.ndarray) -> np.ndarray:
    """The folds a peer chooses its own settings on inside one training fold: the groups
    left, numbered 0..k-1, or three contiguous blocks when only one group is left."""
    ids, inner = np.unique(groups, return_inverse=True)
    if ids.size >= 2:
        return inner
    n = groups.size
    return np.minimum(np.arange(n) * 3 // max(n, 1), 2)


def peer_validation(X: np.ndarray, XL: np.ndarray, y: np.ndarray, folds: np.ndarray,
                    exhaustive_limit: int = EXHAUSTIVE_LIMIT) -> dict[str, float]:
    """Each peer's out-of-fold RMSE on the training data: the whole peer (its subset,
    penalty or trees too) refitted without each fold, that fold predicted. NaN for a peer
    that is skipped (too many subsets, k >= sensors)."""
    sse: dict[str, float] = {}
    for fold in np.unique(folds):
        keep = folds != fold
        fits = fit_peers(X[keep], XL[keep], y[keep], inner_folds(folds[keep]),
                         exhaustive_limit)
        for peer, fit in fits.items():
            if fit.predict is None:
                sse[peer] = math.nan
                continue
            pred = fit.predict((XL if fit.lags else X)[~keep])
            sse[peer] = sse.get(peer, 0.0) + float(np.sum((y[~keep] - pred) ** 2))
    return {peer: math.sqrt(v / len(y)) for peer, v in sse.items()}



def score_peers(job: Job, train: list, test: list, cases: dict) -> None:
    """Fit every peer on ``job``'s training runs and score it on each test run, into
    ``cases`` ((variant, test name, target) -> CaseResult; bench.quick_accuracy's baseline
    uses it too)."""
    from thermal_comp.host.fitting import fold_groups

    period = train[0].period_s
    folds, _ = fold_groups(train)
    X = np.vstack([peer_features(r, job.reference, False) for r in train])
    XL = np.vstack([peer_features(r, job.reference, True) for r in train])
    tests = [(s, peer_features(r, job.reference, False), peer_features(r, job.reference, True), r)
             for s, r in test]
    for t in job.targets:
        y = np.concatenate([peer_target(r, t, job.reference) for r in train])
        validation = peer_validation(X, XL, y, folds)
        for peer, fit in fit_peers(X, XL, y, folds).items():
            for s, F, FL, run in tests:
                err = math.nan if fit.predict is None else \
                    score(run.target(t), fit.predict(FL if fit.lags else F), job.reference,
                          period)
                for variant, _ in job.ours_variants():
                    case = cases[(variant, s.name, t)]
                    case.rmse_um[peer] = err
                    case.peer_sensors[peer] = fit.n_sensors
                    case.peer_validation_um[peer] = validation[peer]
                    if fit.note:
                        case.notes[peer] = fit.note
