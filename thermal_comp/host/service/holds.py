"""Re-touching off without a model: what a shop does today with its probe readings.

``hold``: after each touch the offset is the reading (the last reading held until the next);
before the first touch nothing is corrected. ``extrapolate``: the line through the last two
readings, continued (the last reading held until there are two).
A reading at sample k takes effect from sample k + 1, as the estimators' do.
"""

from __future__ import annotations

import numpy as np


def hold(n: int, index: np.ndarray, value: np.ndarray) -> np.ndarray:
    out = np.zeros(n)
    order = np.argsort(index, kind="stable")
    for k, z in zip(np.asarray(index)[order], np.asarray(value)[order], strict=True):
        out[int(k) + 1:] = z
    return out


def extrapolate(time_s: np.ndarray, index: np.ndarray, value: np.ndarray) -> np.ndarray:
    t = np.asarray(time_s, dtype=float)
    out = np.zeros(t.size)
    order = np.argsort(index, kind="stable")
    idx, val = np.asarray(index)[order].astype(int), np.asarray(value, dtype=float)[order]
    for j, (k, z) in enumerate(zip(idx, val, strict=True)):
        if j == 0 or t[k] <= t[idx[j - 1]]:
            out[k + 1:] = z
            continue
        slope = (z - val[j - 1]) / (t[k] - t[idx[j - 1]])
        out[k + 1:] = z + slope * (t[k + 1:] - t[k])
    return out
