"""How well does an error measured on the training data rank sensor subsets for an unseen run?

A selection method can only be as good as the error it ranks subsets by. Here every subset of
3-5 of the 16 FL_THERMAL sensors is fitted on the training data and scored three ways: the
out-of-fold RMSE (our default's criterion), the training RMSE (paper 000's, and the exhaustive
best subset's) and the RMSE on the unseen test data. Per probe it reports the Spearman rank
correlation of each training-side error with the test error, and where the subset our default
chose ranks among all of them on the test. Case sets: the issue's split (train 0-24 h as one
run in three time blocks, test 24-32 h) and each 8 h cycle held out in turn (the other three
as runs). A rank correlation near 0.4 means that which of two near-equal subsets does better
on one unseen cycle is mostly luck: per-probe wins between good selectors are noise.
docs/selection.md quotes this table.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from bench.bench_selection import LOCO, PROBES, cases_fl
from bench.goal import INFO
from thermal_comp.host.fitting import common_period, fold_groups
from thermal_comp.host.selection import select_sensors

SIZES = (3, 4, 5)
SPLIT = "FL, 0-24 h -> 24-32 h (5)"


def _ranks(a: np.ndarray) -> np.ndarray:
    r = np.empty(a.size)
    r[np.argsort(a, kind="stable")] = np.arange(a.size)
    return r


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Rank correlation (ties broken by order; the errors here are continuous)."""
    return float(np.corrcoef(_ranks(np.asarray(a)), _ranks(np.asarray(b)))[0, 1])


def _grams(X: np.ndarray, y: np.ndarray, folds: np.ndarray, x_mean: np.ndarray,
           sd: np.ndarray, y_mean: float):
    """Per-fold (M, v, s) of [1, standardised X] against centred y."""
    out = []
    for g in np.unique(folds):
        rows = folds == g
        A = np.column_stack([np.ones(int(rows.sum())), (X[rows] - x_mean) / sd])
        yc = y[rows] - y_mean
        out.append((A.T @ A, A.T @ yc, float(yc @ yc)))
    return out


def subset_errors(X, y, folds, Xt, yt):
    """(subsets, out-of-fold RMSE, training RMSE, test RMSE) of every subset in SIZES."""
    x_mean, sd, y_mean = X.mean(axis=0), X.std(axis=0), float(y.mean())
    sd[sd == 0] = 1.0
    per_fold = _grams(X, y, folds, x_mean, sd, y_mean)
    M = sum(g[0] for g in per_fold)
    v = sum(g[1] for g in per_fold)
    s = sum(g[2] for g in per_fold)
    Mt, vt, st = _grams(Xt, yt, np.zeros(len(yt)), x_mean, sd, y_mean)[0]
    subsets, oof, train, test = [], [], [], []
    for k in SIZES:
        for combo in combinations(range(X.shape[1]), k):
            i = np.array([0, *(c + 1 for c in combo)])
            beta = np.linalg.lstsq(M[np.ix_(i, i)], v[i], rcond=None)[0]
            train.append(s - 2 * beta @ v[i] + beta @ M[np.ix_(i, i)] @ beta)
            test.append(st - 2 * beta @ vt[i] + beta @ Mt[np.ix_(i, i)] @ beta)
            sse = 0.0
            for Mf, vf, sf in per_fold:
                b = np.linalg.lstsq((M - Mf)[np.ix_(i, i)], (v - vf)[i], rcond=None)[0]
                sse += sf - 2 * b @ vf[i] + b @ Mf[np.ix_(i, i)] @ b
            oof.append(sse)
            subsets.append(combo)
    n, nt = len(y), len(yt)
    return (subsets, np.sqrt(np.maximum(oof, 0) / n), np.sqrt(np.maximum(train, 0) / n),
            np.sqrt(np.maximum(test, 0) / nt))


def _case_rows(train, test) -> list[dict]:
    X = np.vstack([r.temperatures for r in train])
    Xt = np.vstack([r.temperatures for r in test])
    folds, _ = fold_groups(train)
    run_ids = np.concatenate([np.full(r.n_samples, i) for i, r in enumerate(train)])
    out = []
    for target in PROBES:
        y = np.concatenate([r.target(target) for r in train])
        yt = np.concatenate([r.target(target) for r in test])
        subsets, oof, tr, te = subset_errors(X, y, folds, Xt, yt)
        ours = tuple(sorted(select_sensors(X, y, run_ids, folds, common_period(train)).sensors))
        ours_test = te[subsets.index(ours)] if ours in subsets else float("nan")
        out.append({"target": target, "rho_oof": spearman(oof, te), "rho_train": spearman(tr, te),
                    "ours_pct": float(np.mean(te < ours_test) * 100),
                    "first_by_oof": float(te[np.argmin(oof)]), "ours": float(ours_test),
                    "best": float(te.min()), "median": float(np.median(te))})
    return out


def run() -> list[dict]:
    cases = cases_fl()
    rows: list[dict] = []
    for train, test, _ in cases[SPLIT]:
        for r in _case_rows(train, test):
            rows.append({"name": f"24 h split {r['target']}: rank corr. out-of-fold/test",
                         "value": r["rho_oof"], "unit": "", "goal": INFO,
                         "detail": f"training/test {r['rho_train']:.2f}; ours {r['ours']:.2f} um "
                         f"(better than {100 - r['ours_pct']:.0f} % of subsets), first by "
                         f"out-of-fold {r['first_by_oof']:.2f}, best {r['best']:.2f}, median "
                         f"{r['median']:.2f} um"})
    loco = [r for train, test, _ in cases[LOCO] for r in _case_rows(train, test)]
    for key, what in (("rho_oof", "out-of-fold/test"), ("rho_train", "training/test")):
        v = np.array([r[key] for r in loco])
        rows.append({"name": f"FL one cycle held out: rank corr. {what}", "value": float(v.mean()),
                     "unit": "", "goal": INFO,
                     "detail": f"mean of {v.size} cases, range {v.min():.2f} to "
                     f"{v.max():.2f}"})
    pct = np.array([100 - r["ours_pct"] for r in loco])
    rows.append({"name": "FL one cycle held out: ours better than", "value": float(pct.mean()),
                 "unit": "% subsets", "goal": INFO, "detail": f"mean of {pct.size} cases, median "
                 f"{np.median(pct):.0f} %"})
    return rows


if __name__ == "__main__":
    for row in run():
        print(f"{row['name']:<52} {row['value']:>8.3f} {row['unit']:<9} {row.get('detail', '')}")
