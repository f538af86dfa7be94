"""Host side of the thermal-error compensation box: data, sensor selection, fit, evaluation.

Wings by concern, each imported through its package (docs/architecture.md has the floors):
io → fitting → selection → effects → train → analysis; sim and box apart; cli, commands and
demo on top.
"""

from __future__ import annotations

from thermal_comp.contract import __version__

__all__ = ["__version__", "ThermalSensorSelector"]


def __getattr__(name: str):
    # Lazy so that `import host` stays fast for the CLI (scikit-learn costs ~1 s).
    if name == "ThermalSensorSelector":
        from thermal_comp.host.selection.estimator import ThermalSensorSelector

        return ThermalSensorSelector
    raise AttributeError(name)
