"""The live link to the box: ``host monitor``.
"""

from __future__ import annotations

from host.box.monitor import Monitor
from host.box.state import MonitorError
from host.box.views import render

__all__ = [
    "Monitor",
    "MonitorError",
    "render",
]
