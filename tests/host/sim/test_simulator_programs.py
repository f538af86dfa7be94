"""Spindle programs: each protocol's schedule against its definition (paper 002, paper 000)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from thermal_comp.host.sim import COOL, RUN, ProgramError, build_program


def test_constant_runs_at_three_quarters_of_max_then_cools():
    p = build_program("constant", 4500.0, hours=8, cool_hours=8)
    assert [(s.rpm, s.duration_s, s.phase) for s in p.segments] == [
        (3375.0, 8 * 3600.0, RUN), (0.0, 8 * 3600.0, COOL)]
    assert p.rpm_at(0.0) == 3375.0 and p.rpm_at(8 * 3600.0) == 0.0


def test_step_repeats_quarters_for_fifteen_minutes():
    p = build_program("step", 8000.0, hours=2, cool_hours=1)
    t = np.arange(0, 2 * 3600, 60.0) + 30.0
    expected = np.array([2000, 4000, 6000, 8000])[((t // 900) % 4).astype(int)]
    np.testing.assert_array_equal(p.rpm_at(t), expected)
    assert p.duration_s == 3 * 3600.0 and p.run_s == 2 * 3600.0


def test_random_uses_quarter_levels_and_iso_like_durations_and_is_seeded():
    a = build_program("random", 8000.0, hours=8, cool_hours=0, seed=7)
    b = build_program("random", 8000.0, hours=8, cool_hours=0, seed=7)
    c = build_program("random", 8000.0, hours=8, cool_hours=0, seed=8)
    assert a == b and a != c
    assert {s.rpm for s in a.segments} <= {0.0, 2000.0, 4000.0, 6000.0, 8000.0}
    assert all(s.duration_s % 300 == 0 for s in a.segments[:-1])  # 5-min multiples
    assert sum(s.duration_s for s in a.segments) == 8 * 3600.0
    assert 0.3 < a.mean_run_fraction() < 0.7  # lower than the constant test's 75 %


def test_sine_has_a_one_hour_period_between_its_limits():
    p = build_program("sine", 3000.0, hours=3, cool_hours=0)
    t = np.arange(0, 3 * 3600, 60.0) + 30.0
    rpm = p.rpm_at(t)
    expected = 3000 * (50 / 3000 + (1 - 50 / 3000) * 0.5 * (1 - np.cos(2 * math.pi * t / 3600)))
    np.testing.assert_allclose(rpm, np.round(expected), atol=0.5)
    assert rpm.max() <= 3000 and rpm.min() >= 50


def test_levels_above_max_and_bad_durations_are_refused():
    with pytest.raises(ProgramError, match="above --max-rpm 8000"):
        build_program("constant", 8000.0, rpm=8500.0)
    with pytest.raises(ProgramError, match="level 110 %"):
        build_program("step", 8000.0, levels=(0.5, 1.1))
    with pytest.raises(ProgramError, match="--hours"):
        build_program("step", 8000.0, hours=0)
    with pytest.raises(ProgramError, match="unknown protocol"):
        build_program("ramp")
