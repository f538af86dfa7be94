"""Paper 000's two thermal parameters of a sensor: correlation r and time delay tau.

r (eq. 5) is Pearson's correlation of a temperature with the displacement. tau (eq. 6) is the
lag at the peak of the normalised cross-correlation of the mean-removed signals

    C(tau) = sum_t d~(t) * T~(t + tau) / (n * s_d * s_T),     ~ = mean removed,

so C(0) = r exactly and |C| <= 1. Sign convention: **positive tau means the temperature lags
the displacement** (T at t + tau looks like d at t). The peak is the largest |C| (a sensor that
falls while the tool grows has a negative peak, and its delay is just as meaningful). The search
is limited to |tau| <= max_lag (default a quarter of the run), where at least three quarters of
the samples overlap. The curves are computed with one zero-padded real FFT for all sensors.

With several runs, every run gets its own curve (filters and means never straddle a run
boundary) and the curves are averaged with weights n_run / n_total. The combined r is that
average at lag 0 (the sample-weighted mean of the per-run r) and tau is the peak of the averaged
curve, so a delay that is ambiguous in one run is decided by all of them together.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from thermal_comp.contract.errors import InputError

DEFAULT_MAX_LAG_FRACTION = 0.25


@dataclass
class ThermalParameters:
    """Per-sensor r and tau (tau in samples and seconds) plus the curves they come from."""

    correlations: np.ndarray  # (k,)
    delays_samples: np.ndarray  # (k,) float (integer unless refined)
    delays_s: np.ndarray  # (k,)
    lags: np.ndarray  # (2L+1,) lag in samples for each curve row
    curves: np.ndarray  # (2L+1, k) normalised cross-correlation


def pearson_r(temperatures: np.ndarray, displacement: np.ndarray) -> np.ndarray:
    """Pearson r of each temperature column with the displacement (0 for a constant column)."""
    T = np.asarray(temperatures, dtype=float)
    if T.ndim == 1:
        T = T[:, None]
    d = np.asarray(displacement, dtype=float)
    Tc = T - T.mean(axis=0)
    dc = d - d.mean()
    denom = np.sqrt((Tc ** 2).sum(axis=0) * float(dc @ dc))
    num = dc @ Tc
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(denom > 0, num / np.where(denom > 0, denom, 1.0), 0.0)
    return np.clip(r, -1.0, 1.0)


# Sensors transformed together: a multiple of the widest SIMD group of doubles (8), so the FFT
# groups the columns as it does the whole array at once (the same numbers to the last bit).
FFT_COLUMNS = 8


def _column_blocks(k: int, width: int) -> list[tuple[int, int]]:
    """[a, b) ranges of ``width`` columns covering k; a last block of one column joins the one
    before (numpy sums a lone column pairwise, a block's columns row by row, as the whole)."""
    starts = list(range(0, k, width)) or [0]
    if len(starts) > 1 and k - starts[-1] < 2:
        starts.pop()
    return list(zip(starts, [*starts[1:], k], strict=True))


def cross_correlation(temperatures: np.ndarray, displacement: np.ndarray,
                      max_lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised cross-correlation C(tau) for tau = -max_lag..max_lag, one column per sensor."""
    T = np.asarray(temperatures, dtype=float)
    if T.ndim == 1:
        T = T[:, None]
    d = np.asarray(displacement, dtype=float)
    n = T.shape[0]
    max_lag = int(max(0, min(max_lag, n - 1)))
    lags = np.arange(-max_lag, max_lag + 1)
    mean = T.mean(axis=0)
    dc = d - d.mean()
    dd = float(dc @ dc)
    nfft = 1 << int(n + max_lag).bit_length()  # power of two >= n + max_lag + 1: no wrap
    # sum_t d(t) T(t + tau) = irfft(conj(D) * T)[tau] (negative tau wraps to the end), a few
    # sensors at a time (FFT_COLUMNS), centred there: all 64 of a day at 1 s at once held
    # 400 MB of spectra and centred copies
    spectrum = np.conj(np.fft.rfft(dc, nfft))[:, None]
    k = T.shape[1]
    raw = np.empty((2 * max_lag + 1, k))
    scale = np.empty(k)
    for a, b in _column_blocks(k, FFT_COLUMNS):
        Tc = T[:, a:b] - mean[a:b]
        scale[a:b] = n * np.sqrt((Tc ** 2).mean(axis=0) * dd / n)
        full = np.fft.irfft(spectrum * np.fft.rfft(Tc, nfft, axis=0), nfft, axis=0)
        raw[:max_lag, a:b] = full[nfft - max_lag:]
        raw[max_lag:, a:b] = full[:max_lag + 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        curves = np.where(scale > 0, raw / np.where(scale > 0, scale, 1.0), 0.0)
    return lags, curves


def _peak(lags: np.ndarray, curves: np.ndarray, refine: bool) -> np.ndarray:
    """Lag of the largest |C| per column; optional parabolic refinement between samples."""
    mag = np.abs(curves)
    idx = np.argmax(mag, axis=0)
    out = lags[idx].astype(float)
    if refine:
        for j, i in enumerate(idx):
            if 0 < i < len(lags) - 1:
                y0, y1, y2 = mag[i - 1, j], mag[i, j], mag[i + 1, j]
                den = y0 - 2 * y1 + y2
                if den < 0:
                    out[j] += 0.5 * (y0 - y2) / den
    return out


def default_max_lag(n_samples: int) -> int:
    return max(1, int(n_samples * DEFAULT_MAX_LAG_FRACTION))


def thermal_parameters(segments: Sequence[tuple[np.ndarray, np.ndarray]], period_s: float,
                       max_lag_s: float | None = None, refine: bool = False
                       ) -> ThermalParameters:
    """r and tau of every sensor from one or more runs ``[(temperatures, displacement), ...]``.

    ``max_lag_s`` limits the delay search (default: a quarter of the shortest run).
    """
    if not segments:
        raise InputError("no data to compute correlations from")
    if period_s <= 0:
        raise InputError(f"sample period must be > 0 (got {period_s})")
    lengths = [len(d) for _, d in segments]
    if min(lengths) < 2:
        raise InputError("each run needs at least 2 samples to compute a correlation")
    if max_lag_s is None:
        max_lag = default_max_lag(min(lengths))
    else:
        if max_lag_s < 0:
            raise InputError(f"maximum delay must be >= 0 (got {max_lag_s} s)")
        max_lag = int(round(max_lag_s / period_s))
    max_lag = min(max_lag, min(lengths) - 1)
    total = float(sum(lengths))
    combined = None
    lags = None
    r = None
    for (T, d), n in zip(segments, lengths, strict=True):
        w = n / total
        # r first: its centred copy of the run is not held beside the curves
        r = pearson_r(T, d) * w if r is None else r + pearson_r(T, d) * w
        lags, curves = cross_correlation(T, d, max_lag)
        combined = curves * w if combined is None else combined + curves * w
        del curves
    assert combined is not None and lags is not None and r is not None
    r = np.clip(r, -1.0, 1.0)
    tau = _peak(lags, combined, refine)
    return ThermalParameters(r, tau, tau * period_s, lags, combined)
