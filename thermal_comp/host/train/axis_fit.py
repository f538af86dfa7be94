"""An axis of model.json from a fit: its terms with coefficients, and the metrics that justify it.

One home for the metrics every fitted axis reports (least squares or ridge): training and
out-of-fold RMSE, R², the collinearity diagnostics paper 000's selection exists to keep small.
A fit is typed (``AxisFit``) between the stages and becomes JSON once, in the record.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from thermal_comp.contract.terms import Term
from thermal_comp.host.fitting import condition_number, r_squared, rmse, variance_inflation


@dataclass(frozen=True)
class AxisFit:
    """One axis fitted on fixed terms: intercept, the terms with their coefficients (as
    model.json has them) and the metrics (training and out-of-fold RMSE, R², collinearity)."""

    intercept: float
    terms_json: tuple[Mapping[str, Any], ...]
    metrics: Mapping[str, Any]

    @staticmethod
    def of(terms: Sequence[Term], coef: np.ndarray, intercept: float, X: np.ndarray,
           y: np.ndarray, validation_rmse_um: float, scheme: str) -> AxisFit:
        """The fit of ``y`` on ``X`` (the columns of ``terms``) with its metrics."""
        residual = y - (X @ coef + intercept if len(terms) else np.full(y.size, intercept))
        vif = variance_inflation(X)
        return AxisFit(float(intercept), tuple(
            {**t.to_json(), "coef": float(c)} for t, c in zip(terms, coef, strict=True)), {
            "train_rmse_um": rmse(residual),
            "validation_rmse_um": validation_rmse_um,
            "raw_rms_um": rmse(y),
            "r2": r_squared(y, y - residual),
            "max_abs_um": float(np.max(np.abs(residual))),
            "condition_number": condition_number(X),
            "vif": {t.name: float(v) for t, v in zip(terms, vif, strict=True)},
            "validation": scheme,
            "n_samples": int(y.size),
        })

    @property
    def terms(self) -> list[Term]:
        """The terms as model.json gives them back (Term.from_json of each)."""
        return [Term.from_json(t) for t in self.terms_json]

    def to_json(self) -> dict:
        """The axis fields (unit, intercept, terms, metrics); fresh dicts, the caller's own."""
        return {"unit": "um", "intercept": self.intercept,
                "terms": [dict(t) for t in self.terms_json], "metrics": dict(self.metrics)}


def axis_dict(terms: Sequence[Term], coef: np.ndarray, intercept: float, X: np.ndarray,
              y: np.ndarray, validation_rmse_um: float, scheme: str) -> dict:
    """The axis fields (unit, intercept, terms, metrics) of a fit of ``y`` on ``X``."""
    return AxisFit.of(terms, coef, intercept, X, y, validation_rmse_um, scheme).to_json()
