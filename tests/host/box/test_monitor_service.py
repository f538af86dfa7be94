"""host monitor's in-service lines (issue 42): the estimate, the last residual, refusals."""

from __future__ import annotations

from thermal_comp.contract import protocol
from thermal_comp.host.box.state import MonitorState
from thermal_comp.host.box.views import service_lines


def test_estimate_residual_and_repeated_refusals_are_shown():
    state = MonitorState("pty")
    state.info = protocol.Info("0.1.0", "h", True, 60000, ("dx_um", "dy_um", "dz_um"), ())
    state.status_report = protocol.StatusReport(
        0x0800, 9, 1, (0,), 0, service=(protocol.AxisService(4706, 5000, 0),
                                         protocol.AxisService(0, 45294, 3), None))
    lines = service_lines(state)
    assert "+4.706" in lines[0] and "+5.000" in lines[0] and "REFUSED" not in lines[0]
    assert "3 REFUSED" in lines[1][:79] and "(3 readings refused in a row" in lines[1]
    assert "off" in lines[2]
    state.status_report = protocol.StatusReport(0x0800, 9, 1, (0,), 0)  # a box before MEAS
    assert service_lines(state) == []


def test_a_reopened_axis_with_new_refusals_shows_both_marks_within_80_columns():
    """The screen clips a line at 79 columns: the marks come before their explanations, and
    the refusals (today's alarm) before the re-openings (history)."""
    state = MonitorState("pty")
    state.info = protocol.Info("0.1.0", "h", True, 60000, ("dx_um", "dy_um", "dz_um"), ())
    state.status_report = protocol.StatusReport(
        0x0800, 9, 1, (0,), 0, service=(protocol.AxisService(0, 0, 0, 0),
                                         protocol.AxisService(1200, 800, 1, 1),
                                         protocol.AxisService(60000, 9000, 2, 1)))
    lines = service_lines(state)
    assert "REOPENED" not in lines[0] and "refused" not in lines[0]
    assert "1 refused, REOPENED 1x" in lines[1][:78]
    assert "2 REFUSED, REOPENED 1x" in lines[2][:78], lines[2]  # 78: the clip adds "…"
    assert "(2 readings refused in a row, beyond the gate" in lines[2]
