"""Paper 000's sensor selection as a scikit-learn feature selector (``ThermalSensorSelector``).

Kept apart from host.selection so the CLI does not import scikit-learn; import it as
``host.ThermalSensorSelector`` or ``host.selection.ThermalSensorSelector``.
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator
from sklearn.feature_selection import SelectorMixin
from sklearn.utils.validation import check_is_fitted, validate_data

from thermal_comp.host.selection.clustering import DEFAULT_RESTARTS
from thermal_comp.host.selection.selector import (
    DEFAULT_BLOCKS,
    DEFAULT_GROUPS,
    DEFAULT_MAX_SENSORS,
    SelectionError,
    fold_labels,
    select_sensors,
)
from thermal_comp.host.selection.selector import check_params as _check_params


class ThermalSensorSelector(SelectorMixin, BaseEstimator):
    """Paper 000's sensor selection as a scikit-learn feature selector.

    ``fit(X, y)`` takes temperatures (n_samples, n_sensors) sampled every ``period_s`` seconds
    and one displacement; ``groups`` (optional, per sample) marks separate runs, which are then
    correlated separately and used for leave-one-run-out validation. Rows must be in time order.

    Fitted attributes: ``correlations_``, ``delays_`` (seconds), ``labels_`` (group per sensor,
    0 = smallest group), ``representatives_`` and ``support_indices_`` (column indices),
    ``ec_curve_``, ``ec_errors_``, ``n_features_in_``.
    """

    def __init__(self, n_groups: int = DEFAULT_GROUPS, max_sensors: int = DEFAULT_MAX_SENSORS,
                 selection: str = "validated", period_s: float = 1.0,
                 max_delay_s: float | None = None, n_blocks: int = DEFAULT_BLOCKS,
                 n_restarts: int = DEFAULT_RESTARTS, random_state: int = 0) -> None:
        self.n_groups = n_groups
        self.max_sensors = max_sensors
        self.selection = selection
        self.period_s = period_s
        self.max_delay_s = max_delay_s
        self.n_blocks = n_blocks
        self.n_restarts = n_restarts
        self.random_state = random_state

    def fit(self, X, y, groups=None):
        X, y = validate_data(self, X, y, y_numeric=True, dtype=np.float64)
        _check_params(self.n_groups, self.max_sensors, self.selection)
        if self.n_blocks < 2:
            raise SelectionError(f"n_blocks must be >= 2 (got {self.n_blocks})")
        n = X.shape[0]
        run_ids = np.zeros(n, dtype=int) if groups is None else np.asarray(groups)
        if run_ids.shape != (n,):
            raise SelectionError(f"groups must have one label per sample ({n}), "
                                 f"got shape {run_ids.shape}")
        need = 2 if self.selection == "paper" else self.n_blocks
        if n < need:
            raise SelectionError(f"selection '{self.selection}' needs at least {need} samples, "
                                 f"got {n} sample{'s' if n != 1 else ''}")
        folds = fold_labels(run_ids, self.n_blocks)
        result = select_sensors(X, y, run_ids, folds, self.period_s,
                                n_groups=self.n_groups, max_sensors=self.max_sensors,
                                method=self.selection, max_delay_s=self.max_delay_s,
                                n_restarts=self.n_restarts, seed=self.random_state)
        self.result_ = result
        self.correlations_ = result.correlations
        self.delays_ = result.delays_s
        self.labels_ = result.labels
        self.representatives_ = np.array(result.representatives, dtype=int)
        self.support_indices_ = np.array(result.sensors, dtype=int)
        self.ec_curve_ = np.array(result.ec.curve)
        self.ec_errors_ = np.array(result.ec.errors)
        return self

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.target_tags.required = True  # the selection is driven by the displacement y
        return tags

    def _get_support_mask(self):
        check_is_fitted(self, "support_indices_")
        mask = np.zeros(self.n_features_in_, dtype=bool)
        mask[self.support_indices_] = True
        return mask
