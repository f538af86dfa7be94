"""The live link to the box: ``host monitor``.
"""

from __future__ import annotations

from thermal_comp.host.box.monitor import Monitor
from thermal_comp.host.box.state import MonitorError
from thermal_comp.host.box.views import render

__all__ = [
    "Monitor",
    "MonitorError",
    "render",
]
