"""The whole thermal model as a scikit-learn estimator (``ThermalModel``): selection, channel
budget, effects and fit of ``host.train.train_model``, behind ``fit``/``predict``.

Why: a user's own pipeline (unit conversion, resampling, a grid search over ``max_sensors``)
can end in the model the box runs, and reach the box from Python:
``codegen.export_to_c(ThermalModel(...).fit(X, y))`` is the firmware header, the way
m2cgen's ``export_to_c`` turns a fitted estimator into C. Imported by name (it imports
scikit-learn; ``host.train`` itself does not).

Rows are samples in time order, ``period_s`` apart; the columns of ``X`` are the temperatures
(°C) named by ``sensor_names``, then the auxiliary inputs named by ``aux_names`` (e.g. spindle
speed). ``y`` is one displacement (µm) or several (one column per axis, named by
``target_names``). ``groups`` (optional, one label per sample) marks separate runs: the
dynamic terms restart at each run's first sample and validation leaves one run out, exactly
as ``host train`` does with several CSV files.

Column names: a DataFrame's (``feature_names_in_``, set by scikit-learn for pandas and any
dataframe-protocol object, or any object with a ``columns`` attribute) name the sensors and
aux inputs when ``sensor_names`` is not given; ``aux_names`` then picks the aux columns by name,
wherever they are. A ``y`` with a ``name`` (a Series) or ``columns`` names the axes. Those names
reach model.json and everything made from it (the header, the report's wiring sheet).

Units: the box feeds the model °C from its thermocouples. A model fitted on scaled columns
(after a StandardScaler, MinMaxScaler, MaxAbsScaler or RobustScaler, recognised by the exact
statistics those leave) would run on the box without its scaler: ``to_model_json`` refuses it,
and so does ``codegen.export_to_c`` for a Pipeline with any step before the model, naming the
step (it is neither dropped nor guessed at). ``EXPECTED_FAILED_CHECKS`` names the scikit-learn
estimator checks this regressor fails, each with its reason
(tests/host/train/test_sklearn_checks.py).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.utils.validation import check_is_fitted, validate_data

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import spec_of
from thermal_comp.host.fitting import Reference, axis_terms, design_matrix
from thermal_comp.host.io import Run
from thermal_comp.host.train.options import TrainOptions
from thermal_comp.host.train.pipeline import train_model

MIN_SAMPLES = 4  # host train's least (the nested folds and the filters need a few samples)

# scikit-learn's estimator checks this regressor fails by design, with the reason (passed as
# ``expected_failed_checks`` to check_estimator / parametrize_with_checks in the tests).
EXPECTED_FAILED_CHECKS = {
    "check_methods_sample_order_invariance":
        "rows are a time series: the lag and rate filters and the start reference run over "
        "the samples in their order, so a reordered X is another input history",
    "check_methods_subset_invariance":
        "rows are a time series: a subset of rows restarts the filters and the start "
        "reference at its first row, so its predictions differ from the whole run's",
    "check_positive_only_tag_during_fit":
        "not about negative values (temperatures from -40 degC are read; tested apart): the "
        "check fits iris with y sorted by class, so every validation block of the one run "
        "has a constant target, and a target without drift in every training block is "
        "refused as nothing to model",
}
# what each scikit-learn scaler leaves in every column of its output, exactly
_SCALED = {"standardised (each column has mean 0 and standard deviation 1: a StandardScaler's "
           "output)": lambda X: (np.abs(X.mean(axis=0)) < 1e-9).all()
           and (np.abs(X.std(axis=0) - 1) < 1e-9).all(),
           "min-max scaled (each column spans exactly 0..1: a MinMaxScaler's output)":
           lambda X: (X.min(axis=0) == 0).all() and (np.abs(X.max(axis=0) - 1) < 1e-12).all(),
           "max-abs scaled (each column's largest magnitude is exactly 1: a MaxAbsScaler's "
           "output)": lambda X: (np.abs(np.abs(X).max(axis=0) - 1) < 1e-12).all(),
           "robust-scaled (each column has median 0 and interquartile range 1: a "
           "RobustScaler's output)": lambda X: (np.abs(np.median(X, axis=0)) < 1e-9).all()
           and (np.abs(np.subtract(*np.percentile(X, [75, 25], axis=0)) - 1) < 1e-9).all()}


def _names_of(obj: Any) -> list[str] | None:
    """Column names of a DataFrame-like object (anything with ``columns``), else None."""
    cols = getattr(obj, "columns", None)
    if cols is None or isinstance(obj, np.ndarray):
        return None
    try:
        return [str(c) for c in list(cols)]
    except TypeError:
        return None


def _scaled(X: np.ndarray) -> str | None:
    """How the columns of X look scaled, if they carry a scaler's exact signature."""
    if X.shape[0] < 3:
        return None
    for what, test in _SCALED.items():
        if test(X):
            return what
    return None


class ThermalModel(RegressorMixin, BaseEstimator):
    """``host train`` as a regressor: ``fit(X, y, groups=None)``, ``predict(X, groups=None)``,
    ``to_model_json()``.

    ``n_jobs``: processes for the nested folds of long runs (``host train --jobs``; None or
    -1: the default, this process alone, host.parallel.default_workers; the model does not
    depend on it).

    Its defaults are host train's (host.train.options.TrainOptions), checked there.

    Fitted attributes: ``model_`` (the model.json dict), ``axes_`` (target names),
    ``sensors_`` (the thermocouples the box reads), ``columns_`` (the name of each column of
    X), ``n_features_in_``, ``feature_names_in_`` (from a DataFrame), ``inputs_scaled_`` (how
    the temperatures looked scaled, or None).
    """

    def __init__(self, sensor_names: Sequence[str] | None = None,
                 aux_names: Sequence[str] = (), target_names: Sequence[str] | None = None,
                 period_s: float = 1.0, max_sensors: int = TrainOptions.max_sensors,
                 n_groups: int = TrainOptions.groups, selection: str = TrainOptions.selection,
                 effects: bool = TrainOptions.effects,
                 max_channels: int = TrainOptions.max_channels,
                 n_blocks: int = TrainOptions.n_blocks, reference: str | None = None,
                 family: str = TrainOptions.fit,
                 fill_channels: bool = TrainOptions.fill_channels,
                 bending: Sequence[str] = (), prefilter_s: float = TrainOptions.prefilter_s,
                 random_state: int = TrainOptions.seed, n_jobs: int | None = None) -> None:
        self.sensor_names = sensor_names
        self.aux_names = aux_names
        self.target_names = target_names
        self.period_s = period_s
        self.max_sensors = max_sensors
        self.n_groups = n_groups
        self.selection = selection
        self.effects = effects
        self.max_channels = max_channels
        self.n_blocks = n_blocks
        self.reference = reference
        self.family = family  # host train --fit (ridge, ols, auto): ``fit`` is the method
        self.fill_channels = fill_channels
        self.bending = bending  # host train --bending: targets a column's bending moves
        self.prefilter_s = prefilter_s  # host train --prefilter-s: the ridge's low-pass (s)
        self.random_state = random_state
        # host train --jobs: None or -1 (scikit-learn's "every processor") the default
        self.n_jobs = n_jobs

    # ---- helpers ---------------------------------------------------------------------------
    def _names(self, n_features: int) -> tuple[list[str], list[str]]:
        aux = list(self.aux_names)
        columns = getattr(self, "columns_", None)
        if self.sensor_names is None and columns is not None and len(columns) == n_features:
            unknown = [a for a in aux if a not in columns]
            if unknown:
                raise InputError(f"aux_names {unknown} are not columns of X "
                                 f"({', '.join(columns)})")
            return [c for c in columns if c not in aux], aux
        n_temp = n_features - len(aux)
        if n_temp < 1:
            raise InputError(f"X has {n_features} columns, {len(aux)} of them aux: no "
                             "temperature column left")
        sensors = (list(self.sensor_names) if self.sensor_names is not None
                   else [f"T{i + 1:02d}" for i in range(n_temp)])
        if len(sensors) != n_temp:
            raise InputError(f"sensor_names has {len(sensors)} names, X has {n_temp} "
                             "temperature columns")
        return sensors, aux

    def _runs(self, X: np.ndarray, Y: np.ndarray | None, groups, targets: list[str]
              ) -> list[Run]:
        n = X.shape[0]
        labels = np.zeros(n, dtype=int) if groups is None else np.asarray(groups)
        if labels.shape != (n,):
            raise InputError(f"groups must have one label per sample ({n}), got shape "
                             f"{labels.shape}")
        sensors, aux = self._names(X.shape[1])
        runs = []
        for k, g in enumerate(dict.fromkeys(labels.tolist())):
            rows = np.flatnonzero(labels == g)
            if np.any(np.diff(rows) != 1):
                raise InputError(f"the samples of run {g!r} are not contiguous: give each "
                                 "run's rows together, in time order")
            t = np.arange(rows.size, dtype=float) * float(self.period_s)
            disp = (Y[rows] if Y is not None else np.zeros((rows.size, len(targets))))
            temps, auxes = self._split(X[rows], sensors, aux)
            runs.append(Run(path=f"run{k + 1}", time_s=t, sensor_names=list(sensors),
                            temperatures=temps, target_names=list(targets),
                            displacements=disp, aux_names=list(aux), aux=auxes))
        return runs

    def _split(self, X: np.ndarray, sensors: list[str], aux: list[str]
               ) -> tuple[np.ndarray, np.ndarray | None]:
        """X's temperature and aux columns: by name when X's columns are named, else the
        temperatures first, then the aux inputs."""
        columns = getattr(self, "columns_", None)
        if columns is not None and self.sensor_names is None and len(columns) == X.shape[1]:
            temps = X[:, [columns.index(n) for n in sensors]]
            return temps, X[:, [columns.index(n) for n in aux]] if aux else None
        return X[:, :len(sensors)], X[:, len(sensors):] if aux else None

    # ---- scikit-learn API ------------------------------------------------------------------
    def fit(self, X, y, groups=None):
        generic = _names_of(X)  # any object with columns; pandas' also become feature_names_in_
        y_names = _names_of(y) or ([str(y.name)] if getattr(y, "name", None) is not None
                                   else None)
        X, y = validate_data(self, X, y, y_numeric=True, multi_output=True, dtype=np.float64)
        if X.shape[0] < MIN_SAMPLES:
            raise InputError(f"n_samples = {X.shape[0]}: a thermal model needs at least "
                             f"{MIN_SAMPLES} samples in time order")
        named = getattr(self, "feature_names_in_", None)
        self.columns_ = ([str(c) for c in named] if named is not None
                         else generic if generic is not None and len(generic) == X.shape[1]
                         else None)
        Y = y.reshape(-1, 1) if y.ndim == 1 else y
        targets = (list(self.target_names) if self.target_names is not None
                   else y_names if y_names is not None and len(y_names) == Y.shape[1]
                   else (["y"] if y.ndim == 1 else [f"y{i}" for i in range(Y.shape[1])]))
        if len(targets) != Y.shape[1]:
            raise InputError(f"target_names has {len(targets)} names, y has {Y.shape[1]} "
                             "columns")
        sensors, aux = self._names(X.shape[1])
        if self.columns_ is None:
            self.columns_ = [*sensors, *aux]
        self.inputs_scaled_ = _scaled(self._split(X, sensors, aux)[0])
        runs = self._runs(X, Y, groups, targets)
        kwargs = {} if self.reference is None else {"reference": self.reference}
        self.model_ = train_model(runs, targets, sensors=sensors, aux=aux,
                                  max_sensors=self.max_sensors, groups=self.n_groups,
                                  effects=self.effects, selection=self.selection,
                                  n_blocks=self.n_blocks, seed=self.random_state,
                                  max_channels=self.max_channels, fit=self.family,
                                  fill_channels=self.fill_channels,
                                  bending=list(self.bending), prefilter_s=self.prefilter_s,
                                  jobs=None if self.n_jobs in (None, -1) else self.n_jobs,
                                  quiet=True, **kwargs)
        self.axes_ = targets
        self.sensors_ = [c["sensor"] for c in self.model_["channels"]]
        self._single = y.ndim == 1
        return self

    def predict(self, X, groups=None):
        """The float model's output per sample (µm): what the box computes, to within the
        fixed-point bound, referenced as the model is (``start``: change since each run's
        start); (n,) for one axis, (n, n_axes) for several."""
        check_is_fitted(self, "model_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        runs = self._runs(X, None, groups, self.axes_)
        spec = spec_of(self.model_)
        ref = Reference.of_model(spec)
        out = np.empty((X.shape[0], len(self.axes_)))
        start = 0
        for run in runs:
            cols = run.columns()
            for a, name in enumerate(self.axes_):
                terms, coefs, intercept = axis_terms(spec, name)
                M = design_matrix(terms, cols, spec.sample_period_s)
                pred = intercept + (M @ coefs if coefs.size else 0.0)
                out[start:start + run.n_samples, a] = ref.apply(pred)
            start += run.n_samples
        return out[:, 0] if self._single else out

    def to_model_json(self, before: Sequence[Any] = ()) -> dict:
        """The model.json dict (``contract.model_file.write_model`` writes it; codegen reads
        it): what the box runs, which feeds the model °C.

        ``before``: the steps of a Pipeline ahead of this model (``codegen.export_to_c`` of a
        Pipeline passes them). Only ``None``/"passthrough" steps are allowed: any other step
        changes what the coefficients are per, and the box would not apply it, so it is
        refused, named; neither dropped nor guessed at. A model fitted on columns that carry a
        scaler's exact signature is refused the same way."""
        check_is_fitted(self, "model_")
        import copy

        for step in before:
            if step is None or step == "passthrough":
                continue
            kind = type(step).__name__
            raise InputError(
                f"the Pipeline transforms the inputs before the thermal model ({kind}): the "
                "model's coefficients are per transformed unit, while the box feeds the model "
                "°C from its thermocouples and applies no transformer, so the export would "
                "compute something else; it is neither dropped nor folded into the "
                "coefficients here. Fit ThermalModel on °C (it standardises internally for the "
                "ridge); if the steps only bring the data to °C (kelvin to °C, say), export the "
                "model step itself: codegen.export_to_c(pipeline[-1])")
        if getattr(self, "inputs_scaled_", None):
            raise InputError(
                f"this model was fitted on temperatures that look {self.inputs_scaled_}, but "
                "the box feeds the model °C: its coefficients would be applied to the wrong "
                "numbers. Fit it on °C (it standardises internally for the ridge); a scaler "
                "before the model is not folded into the coefficients")
        return copy.deepcopy(self.model_)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.target_tags.multi_output = True
        return tags
