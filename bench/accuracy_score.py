"""One score for every column of the accuracy bench: a run's test RMSE, referenced at its
start (``start``) or plain (``none``). Ours and the peers are scored by this one function, so a
difference between columns is the models', never the scoring's."""

from __future__ import annotations

import numpy as np

REF_WINDOW_S = 300.0  # the start reference before the project had one: the first 5 min

try:  # the project's start reference (issue 13); the same definition stands in before it
    from thermal_comp.host.fitting.reference import Reference, causal_reference
except ImportError:  # pragma: no cover - main before the reference landed
    Reference = None  # type: ignore[assignment,misc]

    def causal_reference(values: np.ndarray, samples: int) -> np.ndarray:
        values = np.asarray(values, dtype=float)
        if values.shape[0] == 0:
            return values.copy()
        k = max(1, min(int(samples), values.shape[0]))
        counts = np.arange(1, k + 1, dtype=float).reshape((-1,) + (1,) * (values.ndim - 1))
        head = np.cumsum(values[:k], axis=0) / counts
        return np.concatenate([head, np.repeat(head[-1:], values.shape[0] - k, axis=0)])


def reference_window(period_s: float) -> int:
    """K, the samples of the start reference: the project's (host.fitting.reference), else
    ``REF_WINDOW_S`` of samples."""
    if Reference is not None:
        return int(Reference.of_kind("start").samples)
    return max(1, int(round(REF_WINDOW_S / period_s)))


def referenced(x: np.ndarray, k: int) -> np.ndarray:
    """``x`` minus its start reference: sample n minus the mean of samples 0..min(n, k-1).

    A series (n,) or columns (n, m) of one run (call it per run); the reference is
    host.fitting.reference.causal_reference, the one the model and the box use.
    """
    x = np.asarray(x, dtype=float)
    return x - causal_reference(x, k)


def score(measured: np.ndarray, predicted: np.ndarray, reference: str, period_s: float) -> float:
    """Test RMSE (um) of one run, the same for every column (see the module docstring)."""
    measured = np.asarray(measured, dtype=float)
    predicted = np.asarray(predicted, dtype=float)
    if reference == "start":
        k = reference_window(period_s)
        err = referenced(predicted, k) - referenced(measured, k)
    elif reference == "none":
        err = predicted - measured
    else:
        raise ValueError(f"unknown reference {reference!r}")
    return float(np.sqrt(np.mean(err * err)))

