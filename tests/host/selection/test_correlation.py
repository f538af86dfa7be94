"""r and tau against independent answers: numpy.corrcoef, known shifts, numpy.correlate."""

from __future__ import annotations

import numpy as np
import pytest

from thermal_comp.host.selection import cross_correlation, pearson_r, thermal_parameters


def _smooth_noise(n: int, seed: int, width: int = 25) -> np.ndarray:
    """Band-limited random signal: white noise smoothed by a moving average (seeded)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=n + width)
    return np.convolve(x, np.ones(width) / width, mode="valid")[:n]


def test_r_equals_numpy_corrcoef():
    rng = np.random.default_rng(0)
    d = rng.normal(size=300)
    T = np.column_stack([d * 2 + rng.normal(size=300), -d + rng.normal(size=300),
                         rng.normal(size=300) + 25.0])
    expected = [np.corrcoef(T[:, j], d)[0, 1] for j in range(3)]
    np.testing.assert_allclose(pearson_r(T, d), expected, rtol=0, atol=1e-12)
    params = thermal_parameters([(T, d)], period_s=60.0)
    np.testing.assert_allclose(params.correlations, expected, rtol=0, atol=1e-12)


def test_constant_column_has_zero_correlation_not_nan():
    d = np.arange(10.0)
    T = np.column_stack([np.full(10, 20.0), d])
    assert pearson_r(T, d).tolist() == pytest.approx([0.0, 1.0])


@pytest.mark.parametrize("shift", [0, 1, 7, -5, 40])
def test_integer_shift_is_recovered_exactly(shift):
    n, period = 2000, 15.0
    s = _smooth_noise(n + 200, seed=3)
    d = s[100:100 + n]
    T = s[100 - shift:100 - shift + n]  # T(t) = d(t - shift): the temperature lags by shift
    params = thermal_parameters([(T[:, None], d)], period_s=period, max_lag_s=100 * period)
    assert params.delays_samples[0] == shift
    assert params.delays_s[0] == shift * period


@pytest.mark.parametrize("shift", [0.3, 2.5, 6.8, -3.4])
def test_subsample_shift_within_half_a_sample(shift):
    # a slow sine sampled with a fractional delay; both the integer peak and the refined
    # (parabolic) peak must be within half a sample of the true delay
    n = 3000
    t = np.arange(n, dtype=float)
    d = np.sin(2 * np.pi * t / 400.0) + 0.5 * np.sin(2 * np.pi * t / 157.0)
    T = np.sin(2 * np.pi * (t - shift) / 400.0) + 0.5 * np.sin(2 * np.pi * (t - shift) / 157.0)
    for refine in (False, True):
        params = thermal_parameters([(T[:, None], d)], period_s=1.0, max_lag_s=50, refine=refine)
        assert abs(params.delays_samples[0] - shift) <= 0.5
    assert abs(params.delays_samples[0] - shift) < 0.1  # refinement does better than rounding


def test_cross_correlation_matches_numpy_correlate():
    rng = np.random.default_rng(4)
    d = rng.normal(size=120)
    T = rng.normal(size=(120, 2))
    lags, curves = cross_correlation(T, d, max_lag=10)
    dc = d - d.mean()
    for j in range(2):
        Tc = T[:, j] - T[:, j].mean()
        full = np.correlate(Tc, dc, mode="full")  # index n-1+k: sum_t dc[t] * Tc[t+k]
        expected = full[119 - 10:119 + 11] / (120 * dc.std() * Tc.std())
        np.testing.assert_allclose(curves[:, j], expected, atol=1e-12)
    assert lags.tolist() == list(range(-10, 11))


def test_negative_correlation_peak_is_found_by_magnitude():
    s = _smooth_noise(1500, seed=5)
    d = s[50:1050]
    T = -s[50 - 12:1050 - 12]
    params = thermal_parameters([(T[:, None], d)], period_s=1.0, max_lag_s=60)
    assert params.delays_samples[0] == 12
    assert params.correlations[0] < 0


def test_search_window_limits_the_delay():
    s = _smooth_noise(1500, seed=6)
    d = s[100:1100]
    T = s[100 - 30:1100 - 30]
    params = thermal_parameters([(T[:, None], d)], period_s=1.0, max_lag_s=10)
    assert abs(params.delays_samples[0]) <= 10


def test_several_runs_combine_sample_weighted():
    rng = np.random.default_rng(7)
    runs = []
    for n, seed in ((400, 8), (1200, 9)):
        s = _smooth_noise(n + 50, seed=seed)
        d = s[50:] + 0.3 * rng.normal(size=n)
        T = s[50 - 4:-4][:, None]
        runs.append((T, d))
    params = thermal_parameters(runs, period_s=2.0, max_lag_s=40)
    r_each = [np.corrcoef(T[:, 0], d)[0, 1] for T, d in runs]
    expected = (400 * r_each[0] + 1200 * r_each[1]) / 1600
    assert params.correlations[0] == pytest.approx(expected, abs=1e-12)
    assert params.delays_s[0] == 8.0
