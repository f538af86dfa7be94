"""Host side of the thermal-error compensation box: data, sensor selection, fit, evaluation."""

from __future__ import annotations

__version__ = "0.1.0"


def __getattr__(name: str):
    # Lazy so that `import host` stays fast for the CLI and the firmware tools.
    if name == "ThermalSensorSelector":
        from host.selection import ThermalSensorSelector

        return ThermalSensorSelector
    raise AttributeError(name)
