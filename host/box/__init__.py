"""The live link to the box: ``host monitor``.
"""

from __future__ import annotations

from host.box.monitor import Monitor, MonitorError, render

__all__ = [
    "Monitor",
    "MonitorError",
    "render",
]
