"""Residual structure: is what the model leaves noise, or something it lacks?

Part of closing the loop (docs/effects.md); host.effects.search drives the steps.
"""

from __future__ import annotations

import math

import numpy as np

from thermal_comp.host.fitting import rmse

AUTOCORR_LIMIT = 0.5  # lag-1 autocorrelation above which a residual is "structured"
NOISE_MULTIPLE = 3.0  # ... provided its RMSE is also above this multiple of the noise floor


def rounded(x: float, digits: int) -> float:
    return round(float(x), digits) if math.isfinite(x) else math.nan




def lag1_autocorrelation(residual: np.ndarray, segments: np.ndarray) -> float:
    """Pooled lag-1 autocorrelation, pairs never straddling two segments (runs or blocks)."""
    num = den = 0.0
    for g in np.unique(segments):
        r = residual[segments == g]
        if r.size < 2:
            continue
        r = r - r.mean()
        num += float(r[1:] @ r[:-1])
        den += float(r @ r)
    return num / den if den > 0 else 0.0


def noise_floor(y: np.ndarray, segments: np.ndarray) -> float:
    """Measurement-noise standard deviation from second differences (robust, MAD based).

    A smooth thermal signal has negligible second differences at these periods; white noise
    of sd s gives second differences of sd s*sqrt(6).
    """
    d2 = []
    for g in np.unique(segments):
        v = y[segments == g]
        if v.size >= 3:
            d2.append(np.diff(v, 2))
    if not d2:
        return 0.0
    d = np.concatenate(d2)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(6.0))


def residual_structure(residual: np.ndarray, y: np.ndarray, segments: np.ndarray,
                       floor: float | None = None) -> dict:
    """Is there structure left? lag-1 autocorrelation vs white noise, RMSE vs noise floor.

    ``floor``: the gauge noise if already known (from the full-rate signal: second
    differences of a thinned-out signal would count thermal curvature as noise)."""
    n = residual.size
    white = 2.0 / math.sqrt(max(n, 1))
    ac = lag1_autocorrelation(residual, segments)
    floor = noise_floor(y, segments) if floor is None else floor
    res = rmse(residual)
    above_noise = res > NOISE_MULTIPLE * floor
    structured = above_noise and ac > max(AUTOCORR_LIMIT, white)
    return {"lag1_autocorr": rounded(ac, 4), "white_noise_limit": rounded(white, 4),
            "residual_rmse_um": rounded(res, 4), "noise_floor_um": rounded(floor, 4),
            "above_noise": bool(above_noise), "structured": bool(structured)}
