"""`host compare`: our selection against its peers, trained and tested on the same data.

Every method sees only the training runs (its own choices, fits and any internal validation use
the same folds as ours: leave-one-run-out, or time blocks of one run) and is judged by the RMSE
of its predictions on the test runs. Methods:
- ours as ``host train`` fits it with its defaults (``box_model``): the box's model, a ridge
  over the selected sensors, the free channels, their lags, the speed of every ``aux`` input
  and the effects the loop found;
- ours, ``validated`` (the default selection), ``validated-refined`` (plus the group
  refinement, opt-in) and ``paper`` (paper 000 exactly), each a static least-squares model on
  its selected sensors, so that the selections are compared alone;
- OLS on all sensors;
- the k most correlated sensors (paper 002, k = 4 by default) + OLS;
- an engineering pick given by the user + OLS;
- scikit-learn's SequentialFeatureSelector (forward, as many sensors as ours) + OLS;
- LassoCV on standardised temperatures (its own count);
- the exhaustive best subset of as many sensors as ours (smallest training error), when
  C(n_sensors, k) is affordable; otherwise skipped and said so.
Per axis it also names the best method on this test and the best one the box can read (at
most BOX_CHANNELS sensors): OLS on all sensors often wins and cannot be wired.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from thermal_comp.contract.box import BOX_CHANNELS
from thermal_comp.contract.errors import InputError
from thermal_comp.host.analysis.evaluate import predict
from thermal_comp.host.fitting import (
    Reference,
    common_period,
    fit_linear,
    fold_groups,
    rmse,
    run_labels,
)
from thermal_comp.host.io import Run
from thermal_comp.host.progress import progress
from thermal_comp.host.selection import (
    DEFAULT_BLOCKS,
    DEFAULT_GROUPS,
    DEFAULT_MAX_SENSORS,
    GramCache,
    pearson_r,
)
from thermal_comp.host.train import DEFAULT_REFERENCE, axis_sensors, dropped_reason, train_model

DEFAULT_K_CORRELATED = 4
BOX_MODEL = "ours, as host train fits it (the box's model)"
EXHAUSTIVE_LIMIT = 200_000  # subsets; C(16,5) = 4368 runs, C(64,5) = 7.6 M is skipped


@dataclass
class MethodResult:
    method: str
    sensors: list[str]
    test_rmse_um: float
    test_max_abs_um: float
    fit_time_s: float
    note: str = ""
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"method": self.method, "sensors": self.sensors, "n_sensors": len(self.sensors),
                "test_rmse_um": self.test_rmse_um, "test_max_abs_um": self.test_max_abs_um,
                "fit_time_s": self.fit_time_s, "note": self.note, **self.extra}


def _timed(fn: Callable[[], tuple[list[str], Callable[[np.ndarray], np.ndarray]]]
           ) -> tuple[list[str], Callable[[np.ndarray], np.ndarray], float]:
    t0 = time.perf_counter()
    names, pred = fn()
    return names, pred, time.perf_counter() - t0


def _ols_on(names: list[str], all_names: list[str], X: np.ndarray, y: np.ndarray
            ) -> tuple[list[str], Callable[[np.ndarray], np.ndarray]]:
    idx = [all_names.index(n) for n in names]
    fit = fit_linear(X[:, idx], y)
    return names, lambda Xt: fit.predict(Xt[:, idx])


def best_subset(X: np.ndarray, y: np.ndarray, k: int, quiet: bool = True) -> list[int]:
    """Exhaustive search: the k columns with the smallest training RMSE (Gram-matrix fits)."""
    cache = GramCache(X, y, np.zeros(len(y), dtype=int))
    best, best_err = None, math.inf
    total = math.comb(X.shape[1], k)
    for combo in progress(combinations(range(X.shape[1]), k), f"best subset of {k}",
                          total=total, quiet=quiet):
        err = cache.train_rmse(combo)
        if err < best_err:
            best, best_err = list(combo), err
    return best or []


def most_correlated(X: np.ndarray, y: np.ndarray, k: int) -> np.ndarray:
    """Paper 002's peer: the columns of the ``k`` largest |Pearson r| with ``y`` (ties in
    column order); `host compare` and the report fit OLS on them."""
    return np.argsort(-np.abs(pearson_r(X, y)), kind="stable")[:k]


def _peers(names: list[str], X: np.ndarray, y: np.ndarray, folds: np.ndarray, k: int,
           k_corr: int, engineering: list[str] | None, exhaustive_limit: int, quiet: bool
           ) -> list[tuple[str, Callable, str]]:
    """(method name, fitting thunk, note) for every peer."""
    from sklearn.feature_selection import SequentialFeatureSelector
    from sklearn.linear_model import LassoCV, LinearRegression
    from sklearn.model_selection import PredefinedSplit
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    cv = PredefinedSplit(folds)
    out: list[tuple[str, Callable, str]] = [
        ("OLS, all sensors", lambda: _ols_on(list(names), names, X, y), ""),
    ]

    def top_correlated():
        return _ols_on([names[i] for i in most_correlated(X, y, k_corr)], names, X, y)
    out.append((f"{k_corr} most correlated (paper 002)", top_correlated, ""))

    if engineering:
        unknown = [n for n in engineering if n not in names]
        if unknown:
            raise InputError(f"--engineering: unknown sensor(s) {', '.join(unknown)} "
                             f"(known: {', '.join(names)})")
        out.append(("engineering pick", lambda: _ols_on(list(engineering), names, X, y), ""))

    def sfs():
        sel = SequentialFeatureSelector(LinearRegression(), n_features_to_select=k,
                                        direction="forward", cv=cv,
                                        scoring="neg_root_mean_squared_error")
        sel.fit(X, y)
        return _ols_on([names[i] for i in np.flatnonzero(sel.get_support())], names, X, y)
    if k < len(names):
        out.append((f"SequentialFeatureSelector (forward, k={k}) + OLS", sfs, ""))
    else:
        out.append((f"SequentialFeatureSelector (forward, k={k}) + OLS", None,
                    "skipped: k equals the number of sensors"))

    def lasso():
        model = make_pipeline(StandardScaler(), LassoCV(cv=cv, max_iter=20000))
        model.fit(X, y)
        coef = model[-1].coef_
        chosen = [names[i] for i in np.flatnonzero(np.abs(coef) > 0)]
        return chosen, model.predict
    out.append(("LassoCV", lasso, ""))

    n_subsets = math.comb(len(names), k)
    label = f"exhaustive best subset (k={k})"
    if n_subsets <= exhaustive_limit:
        out.append((label, lambda: _ols_on([names[i] for i in best_subset(X, y, k, quiet)],
                                           names, X, y), f"{n_subsets} subsets"))
    else:
        out.append((label, None, f"skipped: C({len(names)},{k}) = {n_subsets} subsets > "
                    f"limit {exhaustive_limit}"))
    return out


def compare_methods(train_runs: Sequence[Run], test_runs: Sequence[Run], targets: Sequence[str],
                    *, engineering: list[str] | None = None,
                    k_correlated: int = DEFAULT_K_CORRELATED,
                    max_sensors: int = DEFAULT_MAX_SENSORS, groups: int = DEFAULT_GROUPS,
                    n_blocks: int = DEFAULT_BLOCKS, max_delay_s: float | None = None,
                    exhaustive_limit: int = EXHAUSTIVE_LIMIT, seed: int = 0,
                    methods: Sequence[str] = ("validated", "validated-refined", "paper"),
                    reference: str = DEFAULT_REFERENCE, aux: Sequence[str] = (),
                    box_model: bool = True, bending: Sequence[str] = (),
                    quiet: bool = True) -> dict:
    """Train every method on ``train_runs`` and report its test RMSE per axis.

    ``box_model`` adds the model ``host train`` makes with its defaults (reading ``aux``, and
    ``bending`` for the axes there; its nested validation is skipped: it does not change the
    fit). Every method is judged the
    same way: with the ``start`` reference the peers are fitted on
    the change since each fold's start and every prediction and measurement is referenced at
    its test run's start (host.fitting.reference)."""
    train_runs, test_runs = list(train_runs), list(test_runs)
    names = _check_runs(train_runs, test_runs, targets, bending)
    ref = Reference.of_kind(reference)
    X = np.vstack([r.temperatures for r in train_runs])
    Xt_runs = [r.temperatures for r in test_runs]
    folds, scheme = fold_groups(train_runs, n_blocks)
    X = ref.apply(X, run_labels(train_runs))
    out: dict = {"train": [r.path for r in train_runs], "test": [r.path for r in test_runs],
                 "validation": scheme, "reference": ref.kind, "axes": {}}
    settings = dict(max_sensors=max_sensors, groups=groups, max_delay_s=max_delay_s,
                    n_blocks=n_blocks, seed=seed, reference=reference, nested=False)
    for target in targets:
        y = np.concatenate([ref.apply(r.target(target)) for r in train_runs])
        yt = np.concatenate([ref.apply(r.target(target)) for r in test_runs])
        results: list[MethodResult] = []
        if box_model:
            results.append(_box_model_result(train_runs, test_runs, target, yt, settings,
                                              aux=list(aux),
                                              bending=[target] if target in bending else []))
        ours, k = _selection_results(train_runs, test_runs, target, yt, methods, settings)
        results += ours
        for label, thunk, note in progress(
                _peers(names, X, y, folds, k, k_correlated, engineering, exhaustive_limit, quiet),
                f"peers for {target}", quiet=quiet):
            if thunk is None:
                results.append(MethodResult(label, [], math.nan, math.nan, 0.0, note))
                continue
            chosen, pred_fn, dt = _timed(thunk)
            pred = np.concatenate([ref.apply(pred_fn(Xt)) for Xt in Xt_runs])
            results.append(MethodResult(label, chosen, rmse(yt - pred),
                                        float(np.max(np.abs(yt - pred))), dt, note))
        out["axes"][target] = {"raw_rms_um": rmse(yt), "k": k,
                               "methods": [r.to_json() for r in results],
                               **best_methods(results)}
    return out


def _check_runs(train_runs: list[Run], test_runs: list[Run], targets: Sequence[str],
                bending: Sequence[str]) -> list[str]:
    """The sensor names every run shares, after refusing what cannot be compared: no runs on
    one side, a bending axis not among the targets, other sensor columns, mixed periods."""
    if not train_runs or not test_runs:
        raise InputError("compare needs at least one training and one test run")
    for name in bending:
        if name not in targets:
            raise InputError(f"--bending {name}: not among the targets ({', '.join(targets)})")
    names = train_runs[0].sensor_names
    for run in test_runs:
        if run.sensor_names != names:
            raise InputError(f"{run.path}: sensor columns differ from the training runs")
    common_period(train_runs + test_runs)  # one period for all, or a clear error
    return names


def _box_model_result(train_runs: list[Run], test_runs: list[Run], target: str,
                      yt: np.ndarray, settings: dict, aux: list[str],
                      bending: list[str]) -> MethodResult:
    """The model ``host train`` makes with its defaults (its fit family and the effects it
    kept in the note), scored on the test runs."""
    t0 = time.perf_counter()
    model = train_model(train_runs, [target], aux=aux, **settings, bending=bending)
    dt = time.perf_counter() - t0
    pred = np.concatenate([predict(model, r)[target] for r in test_runs])
    axis = model["axes"][target]
    effects = [e["name"] for e in axis.get("effects", []) if not dropped_reason(e)]
    return MethodResult(
        BOX_MODEL, axis_sensors(axis), rmse(yt - pred), float(np.max(np.abs(yt - pred))),
        dt, f"fit {axis.get('fit', {}).get('family', '?')}"
        + (f"; effects: {', '.join(effects)}" if effects else ""))


def _selection_results(train_runs: list[Run], test_runs: list[Run], target: str,
                       yt: np.ndarray, methods: Sequence[str],
                       settings: dict) -> tuple[list[MethodResult], int]:
    """Each selection method of ours with OLS and no effects, scored on the test runs, and
    the sensors the first chose: the peers get as many."""
    results = []
    k = None
    for method in methods:
        t0 = time.perf_counter()
        model = train_model(train_runs, [target], **settings, effects=False,
                            selection=method, fit="ols")  # the selection methods compared
        dt = time.perf_counter() - t0
        pred = np.concatenate([predict(model, r)[target] for r in test_runs])
        sensors = axis_sensors(model["axes"][target])
        k = len(sensors) if k is None else k  # peers get as many sensors as the default
        label = {"validated": "ours, validated selection + OLS",
                 "paper": "ours, paper 000 exact",
                 "validated-refined": "ours, validated + group refinement",
                 "validated-ec": "ours, validated reps + EC"}.get(method, method)
        results.append(MethodResult(label, sensors, rmse(yt - pred),
                                    float(np.max(np.abs(yt - pred))), dt))
    assert k is not None
    return results, k


def best_methods(results: Sequence[MethodResult]) -> dict:
    """The lowest test RMSE overall and among methods the box can read (<= BOX_CHANNELS
    sensors on one axis); skipped methods (NaN) do not count."""
    scored = [r for r in results if not math.isnan(r.test_rmse_um)]
    fits = [r for r in scored if len(r.sensors) <= BOX_CHANNELS]

    def pick(rs: list[MethodResult]) -> dict | None:
        if not rs:
            return None
        top = min(rs, key=lambda r: r.test_rmse_um)
        return {"method": top.method, "test_rmse_um": top.test_rmse_um}

    return {"best": pick(scored), "best_within_box": pick(fits)}
