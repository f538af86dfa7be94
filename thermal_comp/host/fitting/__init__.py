"""The fitting engine: float features of model terms, least squares, and out-of-fold validation.

``FoldGram`` is the one out-of-fold least-squares engine; selection and the effect search
score their subsets with it, and ``validation_rmse`` judges one design with it.
"""

from __future__ import annotations

from thermal_comp.host.fitting.features import (
    axis_terms,
    coefficient_terms,
    design_matrix,
    first_order_lag,
    linear_prediction,
    shared_filter,
    term_values,
)
from thermal_comp.host.fitting.linear import (
    condition_number,
    fit_linear,
    r_squared,
    rmse,
    variance_inflation,
)
from thermal_comp.host.fitting.out_of_fold import (
    FoldGram,
    out_of_fold_predictions,
    solve_many,
    solve_normal,
    validation_rmse,
)
from thermal_comp.host.fitting.reference import KINDS as REFERENCE_KINDS
from thermal_comp.host.fitting.reference import NO_REFERENCE, Reference, causal_reference
from thermal_comp.host.fitting.ridge import RidgeFit, fit_ridge
from thermal_comp.host.fitting.validation import (
    DEFAULT_BLOCKS,
    common_period,
    fold_groups,
    penalty_groups,
    run_labels,
    stack,
)

__all__ = [
    "RidgeFit",
    "fit_ridge",
    "NO_REFERENCE",
    "Reference",
    "causal_reference",
    "REFERENCE_KINDS",
    "DEFAULT_BLOCKS",
    "FoldGram",
    "axis_terms",
    "coefficient_terms",
    "common_period",
    "condition_number",
    "design_matrix",
    "linear_prediction",
    "first_order_lag",
    "fit_linear",
    "fold_groups",
    "penalty_groups",
    "out_of_fold_predictions",
    "r_squared",
    "rmse",
    "shared_filter",
    "solve_many",
    "solve_normal",
    "run_labels",
    "stack",
    "term_values",
    "validation_rmse",
    "variance_inflation",
]
