"""Float feature values of model terms, computed causally from a run's start as the box does.

The kinds and their meaning are contract.terms (docs/fixed-point.md); this is the float
reference used for fitting and evaluation, ``codegen.fixed`` the integer twin.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from contract.errors import MissingColumnError
from contract.terms import Term


def first_order_lag(x: np.ndarray, alpha: float) -> np.ndarray:
    """y[n] = y[n-1] + alpha*(x[n]-y[n-1]) with y[0] = x[0] (cold start at the first sample)."""
    from scipy.signal import lfilter  # imported here: scipy.signal costs ~1 s at CLI start

    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return x.copy()
    y, _ = lfilter([alpha], [1.0, alpha - 1.0], x, zi=[(1.0 - alpha) * x[0]])
    return y


def term_values(term: Term, columns: Mapping[str, np.ndarray], period_s: float) -> np.ndarray:
    """The float feature of one term over a run's columns (see the module docstring)."""
    if term.kind == "time":
        n = len(next(iter(columns.values())))
        return np.arange(n, dtype=float) * period_s
    if term.source not in columns:
        raise MissingColumnError(f"term {term.name}: column '{term.source}' is not in the data")
    x = np.asarray(columns[term.source], dtype=float)
    if term.kind in ("temp", "speed"):
        return x.copy()
    if term.kind == "speed2":
        return x * x
    if term.kind == "lag":
        return first_order_lag(x, term.params["alpha"])
    if term.kind == "rate":
        return x - first_order_lag(x, term.params["alpha"])
    if term.kind == "square":
        return (x - term.params["ref_c"]) ** 2
    raise AssertionError(term.kind)


def design_matrix(terms: list[Term], columns: Mapping[str, np.ndarray],
                  period_s: float) -> np.ndarray:
    """Columns of term values, shape (n_samples, n_terms)."""
    if not terms:
        n = len(next(iter(columns.values())))
        return np.empty((n, 0))
    return np.column_stack([term_values(t, columns, period_s) for t in terms])


def axis_terms(model: dict, axis: str) -> tuple[list[Term], np.ndarray, float]:
    """Terms, coefficients and intercept of one axis."""
    spec = model["axes"][axis]
    terms = [Term.from_json(t) for t in spec["terms"]]
    coefs = np.array([float(t["coef"]) for t in spec["terms"]])
    return terms, coefs, float(spec["intercept"])
