"""An axis of model.json from a fit: its terms with coefficients, and the metrics that justify it.

One home for the metrics every fitted axis reports (least squares or ridge): training and
out-of-fold RMSE, R², the collinearity diagnostics paper 000's selection exists to keep small.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from thermal_comp.contract.terms import Term
from thermal_comp.host.fitting import condition_number, r_squared, rmse, variance_inflation


def axis_dict(terms: Sequence[Term], coef: np.ndarray, intercept: float, X: np.ndarray,
              y: np.ndarray, validation_rmse_um: float, scheme: str) -> dict:
    """The axis fields (unit, intercept, terms, metrics) of a fit of ``y`` on ``X``."""
    residual = y - (X @ coef + intercept if len(terms) else np.full(y.size, intercept))
    vif = variance_inflation(X)
    return {
        "unit": "um",
        "intercept": float(intercept),
        "terms": [{**t.to_json(), "coef": float(c)} for t, c in zip(terms, coef, strict=True)],
        "metrics": {
            "train_rmse_um": rmse(residual),
            "validation_rmse_um": validation_rmse_um,
            "raw_rms_um": rmse(y),
            "r2": r_squared(y, y - residual),
            "max_abs_um": float(np.max(np.abs(residual))),
            "condition_number": condition_number(X),
            "vif": {t.name: float(v) for t, v in zip(terms, vif, strict=True)},
            "validation": scheme,
            "n_samples": int(y.size),
        },
    }
