"""The ridge's prefilter: its columns and its target low-passed alike before the fit.

The white noise of the probes (sim_dev: sigma 0.2 um) and of the thermocouples (0.03 K and
the MAX31856's step) is no part of the drift a correction can cancel, yet least squares weighs
each sample's noise as much as the slow drift, and the noise on the temperatures pulls the
coefficients. Fitting on both sides passed through the same causal first-order low-pass of
``PREFILTER_TAU_S`` puts the fit's weight on the slow part: system identification's
prefilter (L. Ljung, *System Identification: Theory for the User*, 2nd ed., 1999, on
prefiltering the data). A linear model commutes with the filter, so the coefficients fitted
on the filtered rows are the box's coefficients on its raw readings; nothing on the box
changes. The out-of-fold error that chooses the penalty, and that the model reports, is
scored on the raw rows (host.fitting.ridge.fit_ridge's ``fit_on``): the box sees those.

180 s is below the structure's fastest modelled time constant (the ridge's 900 s lag) and
above the sample periods of the runs measured (15 and 60 s). The time constant was measured
from 60 to 1,200 s on the three sources (docs/training.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from thermal_comp.host.fitting.features import first_order_lag

PREFILTER_TAU_S = 180.0


def prefiltered(X: np.ndarray, y: np.ndarray, lengths: Sequence[int], period_s: float,
                tau_s: float = PREFILTER_TAU_S) -> tuple[np.ndarray, np.ndarray]:
    """``X``'s columns and ``y`` low-passed run by run (``lengths``: each stacked run's
    samples, in order), each run's filter started at its first sample, so a run that starts
    steady has no transient. ``tau_s`` <= 0: the rows unchanged."""
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    if sum(lengths) != len(y) or len(X) != len(y):
        raise ValueError(f"prefiltered: runs of {sum(lengths)} samples for {len(y)} rows")
    if tau_s <= 0:
        return X, y
    alpha = 1.0 - math.exp(-period_s / tau_s)
    Xf, yf = np.empty_like(X), np.empty_like(y)
    start = 0
    for n in lengths:
        rows = slice(start, start + n)
        yf[rows] = first_order_lag(y[rows], alpha)
        for j in range(X.shape[1]):
            Xf[rows, j] = first_order_lag(X[rows, j], alpha)
        start += n
    return Xf, yf
