"""Which thermocouples fill the box's free channels: an L1 ranking of every sensor.

Paper 000's selection (and the effects) choose a few sensors per axis, while the box has 8
inputs and shrinkage copes with more. A lasso over every sensor's temperature and its
first-order lags (referenced as the model is, columns standardised, penalty chosen on the
training folds) ranks the sensors by the weight it gives each one's group of features; the
next-day ridge then reads the selected sensors plus the best-ranked others up to the channel
budget (host.train.free_channels). Measured on unseen runs of three sources in docs/training.md.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from thermal_comp.contract.terms import make_lag, make_temp
from thermal_comp.host.fitting import NO_REFERENCE, Reference, run_labels, stack
from thermal_comp.host.io import Run

MAX_ROWS = 4000  # beyond this the ranking works on every k-th sample: thermal data is smooth
N_ALPHAS = 30  # penalties on the lasso path, from the one that keeps nothing down 1000x


def _screening_design(runs: Sequence[Run], targets: Sequence[str], sensors: Sequence[str], *,
                      period_s: float, taus: Sequence[float], n_blocks: int,
                      reference: Reference) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Standardised temperatures and lags of ``sensors`` (every k-th sample beyond
    ``MAX_ROWS``: a screening, not the model), the referenced targets (one column each) and
    the folds. The design is built once, whatever the number of targets."""
    step = max(1, sum(r.n_samples for r in runs) // MAX_ROWS)
    runs = [r.every(step) for r in runs]  # the lags too
    period_s *= step
    terms = [make_temp(s) for s in sensors]
    terms += [make_lag(s, tau, period_s) for tau in taus if tau > period_s for s in sensors]
    st = stack(runs, terms, targets[0], period_s, n_blocks, reference)
    per_run = run_labels(runs)
    Y = np.column_stack([st.y] + [reference.apply(np.concatenate([r.target(t) for r in runs]),
                                                  per_run) for t in targets[1:]])
    sd = st.X.std(axis=0)
    sd[sd == 0] = 1.0
    return (st.X - st.X.mean(axis=0)) / sd, Y, st.groups


def _by_weight(sensors: list[str], coef: np.ndarray) -> list[str]:
    """Sensors by the summed |weight| of their features (columns: every sensor's temperature,
    then each lag of every sensor), largest first; ties keep the given order."""
    weight = np.abs(coef).reshape(-1, len(sensors)).sum(axis=0)
    return [sensors[i] for i in np.argsort(-weight, kind="stable")]


def l1_ranking(runs: Sequence[Run], target: str, sensors: Sequence[str], *, period_s: float,
               taus: Sequence[float], n_blocks: int,
               reference: Reference = NO_REFERENCE) -> list[str]:
    """``sensors`` ordered by the lasso weight of their temperature and lags on ``target``
    (largest first; sensors the lasso leaves out keep their given order at the end)."""
    from sklearn.linear_model import LassoCV  # imported here: only the ridge fill needs it
    from sklearn.model_selection import PredefinedSplit

    sensors = list(sensors)
    if len(sensors) <= 1:
        return sensors
    Z, Y, groups = _screening_design(runs, [target], sensors, period_s=period_s, taus=taus,
                                     n_blocks=n_blocks, reference=reference)
    y = Y[:, 0]
    if np.unique(groups).size < 2:
        return sensors
    top = float(np.max(np.abs(Z.T @ (y - y.mean())))) / len(y)  # every weight 0 from here
    if not top > 0:
        return sensors
    alphas = top * np.logspace(0, -3, N_ALPHAS)
    lasso = LassoCV(alphas=alphas, cv=PredefinedSplit(groups), max_iter=5000,
                    tol=1e-3).fit(Z, y)
    return _by_weight(sensors, lasso.coef_)


def joint_l1_ranking(runs: Sequence[Run], targets: Sequence[str], sensors: Sequence[str], *,
                     period_s: float, taus: Sequence[float], n_blocks: int,
                     reference: Reference = NO_REFERENCE) -> list[str]:
    """``sensors`` ordered by the weight one multi-task lasso (every target at once, each in
    its own unit, not standardised: the channels go where the drift is) gives each sensor's
    temperature and lags, largest first. Used when the axes share the box's channels
    (host.train.channel_budget); measured in docs/training.md."""
    from sklearn.linear_model import MultiTaskLassoCV  # imported here, as in l1_ranking
    from sklearn.model_selection import PredefinedSplit

    sensors = list(sensors)
    if len(sensors) <= 1:
        return sensors
    Z, Y, groups = _screening_design(runs, targets, sensors, period_s=period_s, taus=taus,
                                     n_blocks=n_blocks, reference=reference)
    if np.unique(groups).size < 2:
        return sensors
    Yc = Y - Y.mean(axis=0)
    top = float(np.max(np.sqrt(((Z.T @ Yc) ** 2).sum(axis=1)))) / len(Yc)
    if not top > 0:
        return sensors
    alphas = top * np.logspace(0, -3, N_ALPHAS)
    lasso = MultiTaskLassoCV(alphas=alphas, cv=PredefinedSplit(groups), max_iter=3000,
                             tol=1e-3).fit(Z, Yc)
    # a feature's weight is the norm of its coefficients over the targets
    return _by_weight(sensors, np.sqrt((lasso.coef_ ** 2).sum(axis=0)))


def fill_free_channels(wired: Sequence[str], rankings: Sequence[Sequence[str]],
                       max_channels: int) -> list[str]:
    """The sensors to add to ``wired`` until ``max_channels``: each axis's ranking in turn
    gives its best sensor not yet wired (so every axis gets its share of the free inputs)."""
    chosen = list(wired)
    queues = [list(r) for r in rankings]
    while len(chosen) < max_channels and any(queues):
        for q in queues:
            while q and q[0] in chosen:
                q.pop(0)
            if q and len(chosen) < max_channels:
                chosen.append(q.pop(0))
    return chosen[len(wired):]
