"""Tilt axes: two gap probes at two heights on the test bar (paper 002's five-probe setup,
ISO 230-3) give the spindle's tilt, an axis in µrad that goes through the box like any other.

``tilt = (upper - lower) / distance``: µm over mm is mrad, so µrad = (upper_um - lower_um) *
1000 / distance_mm; positive when the upper probe reads more than the lower one. The box
computes in integer thousandths of the axis unit either way (nm for µm, nrad for µrad), so a
tilt axis changes nothing in the firmware. Its name ends in ``_urad``, the way displacement
axes end in ``_um``: the box's INFO, the monitor and the LinuxCNC side read the unit from it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from thermal_comp.contract.errors import InputError

AXIS_UNITS = ("um", "urad")  # an axis's unit in model.json: displacement or tilt
TILT_SUFFIX = "_urad"
_SPEC = re.compile(r"\s*([^=,\s]+)\s*=\s*([^=,\s]+)\s*,\s*([^=,\s]+)\s*,\s*([^=,\s]+)\s*")


UNIT_TEXT = {"um": "µm", "urad": "µrad"}  # how people read them


def unit_of(axis: str) -> str:
    """The unit an axis name declares: ``urad`` for a tilt axis, else ``um``."""
    return "urad" if axis.endswith(TILT_SUFFIX) else "um"


def unit_text(axis: str) -> str:
    """The unit of an axis as printed: µm, or µrad for a tilt axis."""
    return UNIT_TEXT[unit_of(axis)]


@dataclass(frozen=True)
class Tilt:
    """A tilt axis ``name`` from the gap probes ``upper`` and ``lower``, ``distance_mm`` apart."""

    name: str
    upper: str
    lower: str
    distance_mm: float

    def __post_init__(self) -> None:
        where = f"--tilt {self.name}"
        if not self.name.endswith(TILT_SUFFIX):
            raise InputError(f"{where}: a tilt axis's name ends in '{TILT_SUFFIX}' (its unit, "
                             f"as displacement axes end in '_um'), e.g. '{self.name}{TILT_SUFFIX}'")
        if self.upper == self.lower:
            raise InputError(f"{where}: the upper and the lower probe are the same column "
                             f"'{self.upper}'")
        if self.name in (self.upper, self.lower):
            raise InputError(f"{where}: the tilt axis cannot be named like one of its probes")
        if not (math.isfinite(self.distance_mm) and self.distance_mm > 0):
            raise InputError(f"{where}: the distance between the probes must be a positive "
                             f"number of mm (got {self.distance_mm!r})")

    @staticmethod
    def parse(text: str) -> Tilt:
        """``NAME=UPPER,LOWER,DISTANCE_MM`` (the command line's form)."""
        m = _SPEC.fullmatch(text)
        if m is None:
            raise InputError(f"--tilt {text!r}: expected NAME=UPPER,LOWER,DISTANCE_MM, e.g. "
                             "tilt_x_urad=dx_top_um,dx_bottom_um,100")
        try:
            distance = float(m.group(4))
        except ValueError:
            raise InputError(f"--tilt {text!r}: the distance {m.group(4)!r} is not a number "
                             "of mm") from None
        return Tilt(m.group(1), m.group(2), m.group(3), distance)

    def of(self, upper_um, lower_um):
        """The tilt in µrad from the two probe readings in µm (numbers or numpy arrays)."""
        return (upper_um - lower_um) * 1000.0 / self.distance_mm

    def to_json(self) -> dict:
        return {"name": self.name, "upper": self.upper, "lower": self.lower,
                "distance_mm": self.distance_mm}

    @staticmethod
    def from_json(d: Mapping) -> Tilt:
        return Tilt(str(d["name"]), str(d["upper"]), str(d["lower"]), float(d["distance_mm"]))


def model_tilts(model: Mapping) -> list[Tilt]:
    """The tilt axes a model.json declares (``tilts``; none for a model without the key)."""
    return [Tilt.from_json(t) for t in model.get("tilts") or []]


def probe_columns(targets: Sequence[str], tilts: Sequence[Tilt]) -> list[str]:
    """The run columns behind ``targets``: a tilt's two probes, every other target itself."""
    by_name = {t.name: t for t in tilts}
    out: list[str] = []
    for name in targets:
        for col in ((by_name[name].upper, by_name[name].lower) if name in by_name else (name,)):
            if col not in out:
                out.append(col)
    return out


def available_axes(header: Sequence[str], axes: Sequence[str], tilts: Sequence[Tilt]) -> list[str]:
    """The axes a run with columns ``header`` can be judged on (a tilt needs both probes)."""
    have = set(header)
    return [a for a in axes if set(probe_columns([a], tilts)) <= have]
