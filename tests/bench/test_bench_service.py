"""The service bench's bound for a bias update: the model's error read exactly and held."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bench.bench_service import exact_hold_rmse


def test_exact_hold_leaves_the_sawtooth_of_a_steady_ramp():
    """An error growing 1 um per hour, read exactly every hour and held: what remains within
    each hour is 0 .. 1 um, a sawtooth of RMS 1/sqrt(3) um (the first hour, before any
    reading, is the same ramp from 0)."""
    t = np.arange(0.0, 8 * 3600.0, 10.0)
    error = t / 3600.0
    got = exact_hold_rmse(error, SimpleNamespace(time_s=t), "dz_um", 3600.0)
    assert got == pytest.approx(1.0 / np.sqrt(3.0), rel=0.01)


def test_exact_hold_removes_an_offset_after_the_first_reading():
    t = np.arange(0.0, 4 * 3600.0, 10.0)
    error = np.full(t.size, 5.0)
    got = exact_hold_rmse(error, SimpleNamespace(time_s=t), "dz_um", 3600.0)
    first_hour = np.count_nonzero(t <= 3600.0) / t.size  # before the first reading applies
    assert got == pytest.approx(5.0 * np.sqrt(first_hour), rel=0.01)
