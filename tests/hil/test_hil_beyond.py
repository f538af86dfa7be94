"""BEYOND on a start-referenced model judges each channel's change since the reference
(docs/firmware.md, "Extrapolation"; issue 41). Measured (scripts/extrapolation_bound.py): the
absolute rule held 90-100 % of every +8 degC simulator day with the default model, where the
model corrected as well as on the training days; judged on the change it never held there.

Native firmware against the host's twin (hil.expect), on a start-referenced model fitted on
examples/sim_step.csv and replayed on sim_random (which it never saw)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from firmware_support import prepare_start_referenced

from thermal_comp.hil import replay as hil_replay
from thermal_comp.hil.checks import Judging
from thermal_comp.hil.expect import BEYOND, HOLD
from thermal_comp.hil.runner import CodeOffset

WARM = 8 * 128  # +8 degC in codes

pytestmark = pytest.mark.skipif(
    shutil.which("gcc") is None or shutil.which("make") is None,
    reason="gcc/make not installed: the native firmware cannot be built")


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    return prepare_start_referenced(
        tmp_path_factory.mktemp("hil_beyond"),
        Judging(max_held_fraction=1.0, max_limited_fraction=1.0, require_no_worse=False))


def _far_hi(setup) -> np.ndarray:
    m = setup.twin.model
    wlo = np.array([c.window_lo_code for c in m.channels])
    whi = np.array([c.window_hi_code for c in m.channels])
    return setup.output.beyond_limits(wlo, whi)[1]


def test_a_warmer_day_is_not_beyond_when_the_change_is_judged(setup):
    n, n_ch = setup.feed.codes.shape
    warm = [CodeOffset(0, n, ch, WARM) for ch in range(n_ch)]
    # the absolute rule would have held: some channel's warm reading is beyond its window
    assert np.any(setup.feed.codes + WARM > _far_hi(setup))
    report, _ = hil_replay.run(setup, warm)
    assert report.ok, report.problems  # every line as the twin expects
    assert not np.any(report.fw_status & (BEYOND | HOLD))


def test_a_slow_runaway_becomes_beyond_once_its_change_exceeds_the_trained_span(setup):
    n = setup.feed.n_samples
    ch = [c.sensor for c in setup.twin.model.channels].index("T05")
    step = max(1, setup.twin.model.channels[ch].max_step_code // 4)  # the guard lets it pass
    report, _ = hil_replay.run(setup, [CodeOffset(300, n, ch, 0, per_sample=step)])
    assert report.ok, report.problems
    beyond = np.flatnonzero(report.fw_status & BEYOND)
    assert beyond.size and beyond[0] > 300  # only once the change is large
    assert np.all(report.fw_status[beyond[0]:] & HOLD)  # dz reads T05: it holds from then on
