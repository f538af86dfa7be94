"""The fault campaign's arithmetic (cnc.faults): the tool error after touch-offs and the
verdict over the rows. The campaign itself runs in `make faults` (part of `make test`)."""

from __future__ import annotations

import numpy as np

from thermal_comp.cnc.faults import KNOWN_GAPS, tool_error_um, verdict


def test_a_touch_off_absorbs_the_error_and_the_offset_in_force_then():
    d = np.array([0.0, 1.0, 3.0, 6.0, 10.0])  # measured drift (um)
    c = np.array([0.0, 1000.0, 2000.0, 0.0, 4000.0])  # the offset commanded (nm)
    e = tool_error_um(d, c, [0, 3])
    # before the touch-off at 3: drift minus offset since the start
    np.testing.assert_allclose(e[:3], [0.0, 0.0, 1.0])
    # from 3 on: the drift since 3 minus the offset change since 3
    np.testing.assert_allclose(e[3:], [0.0, 4.0 - 4.0])


def test_the_verdict_fails_beyond_the_bound_and_when_a_known_gap_closes():
    gap = next(iter(KNOWN_GAPS))
    rows = [{"scenario": "forged line", "where": "w", "ok": True},
            {"scenario": gap, "where": "w", "ok": False}]
    assert verdict(rows) == []
    assert verdict([{**rows[0], "ok": False}, rows[1]]) == ["forged line (w): beyond its bound"]
    closed = verdict([rows[0], {**rows[1], "ok": True}])
    assert closed and "drop it from KNOWN_GAPS" in closed[0]
