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
    assert "3 readings REFUSED in a row" in lines[1]
    assert "off" in lines[2]
    state.status_report = protocol.StatusReport(0x0800, 9, 1, (0,), 0)  # a box before MEAS
    assert service_lines(state) == []
