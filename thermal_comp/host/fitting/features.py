"""Float feature values of model terms, computed causally from a run's start as the box does.

The kinds and their meaning are contract.terms (docs/fixed-point.md); this is the float
reference used for fitting and evaluation, ``codegen.fixed`` the integer twin.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator, Mapping, Sequence

import numpy as np

from thermal_comp.contract.errors import MissingColumnError
from thermal_comp.contract.model_file import ModelSpec, spec_of
from thermal_comp.contract.terms import Term


def first_order_lag(x: np.ndarray, alpha: float) -> np.ndarray:
    """y[n] = y[n-1] + alpha*(x[n]-y[n-1]) with y[0] = x[0] (cold start at the first sample)."""
    from scipy.signal import lfilter  # imported here: scipy.signal costs ~1 s at CLI start

    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return x.copy()
    y, _ = lfilter([alpha], [1.0, alpha - 1.0], x, zi=[(1.0 - alpha) * x[0]])
    return y


def term_values(term: Term, columns: Mapping[str, np.ndarray], period_s: float,
                lag: np.ndarray | None = None) -> np.ndarray:
    """The float feature of one term over a run's columns (see the module docstring).
    ``lag``: for a lag or rate term, ``first_order_lag`` of its source with its alpha if it
    is at hand (a lag and a rate of one sensor and time constant share the filter, as on the
    box)."""
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
        return first_order_lag(x, term.params["alpha"]) if lag is None else lag
    if term.kind == "rate":
        return x - (first_order_lag(x, term.params["alpha"]) if lag is None else lag)
    if term.kind == "square":
        return (x - term.params["ref_c"]) ** 2
    raise AssertionError(term.kind)


def design_matrix(terms: list[Term], columns: Mapping[str, np.ndarray],
                  period_s: float) -> np.ndarray:
    """Columns of term values, shape (n_samples, n_terms)."""
    if not terms:
        n = len(next(iter(columns.values())))
        return np.empty((n, 0))
    return np.column_stack(list(terms_values(terms, columns, period_s)))


def shared_filter(term: Term, columns: Mapping[str, np.ndarray]) -> tuple | None:
    """The filter a lag or rate term runs (its source and alpha; None for other terms, or a
    source not in ``columns``): terms with one key share one ``first_order_lag``."""
    if term.kind not in ("lag", "rate") or term.source not in columns:
        return None
    return term.source, term.params["alpha"]


def terms_values(terms: Sequence[Term], columns: Mapping[str, np.ndarray],
                 period_s: float) -> Iterator[np.ndarray]:
    """``term_values`` of each term in turn, each filter run once: a lag kept while a term
    still to come (a rate, or the lag itself) needs it, the same array it would compute."""
    keys = [shared_filter(t, columns) for t in terms]
    left = Counter(k for k in keys if k is not None)
    lags: dict[tuple, np.ndarray] = {}
    for t, key in zip(terms, keys, strict=True):
        if key is None:
            yield term_values(t, columns, period_s)
            continue
        if key not in lags:
            lags[key] = first_order_lag(np.asarray(columns[t.source], dtype=float), key[1])
        lag = lags[key]
        left[key] -= 1
        if not left[key]:
            del lags[key]
        yield term_values(t, columns, period_s, lag)


def axis_terms(model: Mapping | ModelSpec, axis: str) -> tuple[list[Term], np.ndarray, float]:
    """Terms, coefficients and intercept of one axis (of the typed model, or the dict's)."""
    ax = spec_of(model).axis(axis)
    return list(ax.terms), np.array(ax.coefs, dtype=float), ax.intercept


def coefficient_terms(term_dicts: Sequence[Mapping]) -> tuple[list[Term], np.ndarray]:
    """Terms and coefficients of a JSON term list with ``coef`` (model.json's form, also the
    baseline's and each effect stage's in its report)."""
    return ([Term.from_json(t) for t in term_dicts],
            np.array([float(t["coef"]) for t in term_dicts], dtype=float))


def linear_prediction(terms: Sequence[Term], coefs: np.ndarray, intercept: float,
                      columns: Mapping[str, np.ndarray], period_s: float, n_rows: int
                      ) -> np.ndarray:
    """intercept + the terms' values weighted by ``coefs`` over a run's ``columns`` (filters
    start at its first sample): the float model, unreferenced."""
    if not len(terms):
        return np.full(n_rows, float(intercept))
    return design_matrix(list(terms), columns, period_s) @ coefs + intercept
