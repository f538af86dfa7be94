"""The options of ``host train``, declared once: each with its default and its constraint.

``train_model``'s keywords, the CLI's defaults and choices, and the scikit-learn estimator's
defaults all come from ``TrainOptions``; ``TrainOptions.check`` is the one place an
inconsistent set is refused (before any data is read), each refusal with its reason.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace

from thermal_comp.contract.box import BOX_CHANNELS
from thermal_comp.contract.errors import InputError
from thermal_comp.contract.terms import TC_TYPES as BOX_TC_TYPES
from thermal_comp.contract.tilt import Tilt
from thermal_comp.host.fitting.prefilter import PREFILTER_TAU_S
from thermal_comp.host.selection import (
    DEFAULT_BLOCKS,
    DEFAULT_GROUPS,
    DEFAULT_MAX_SENSORS,
    METHODS,
)
from thermal_comp.host.train.nested import DEFAULT_FIT, FITS
from thermal_comp.host.train.training_data import TrainingError

DEFAULT_REFERENCE = "start"  # ISO 230-3: the probes are zeroed when a test (a day) starts
TC_TYPES = tuple(BOX_TC_TYPES)  # the thermocouple types the box linearises (contract.terms)
DEFAULT_TC_TYPE = "K"
# what a nested fold's own training keeps of the model's options (the rest stay default:
# a fold trains one axis by least squares on runs already loaded)
FOLD_OPTIONS = ("aux", "max_sensors", "groups", "effects", "ambient", "selection",
                "max_delay_s", "n_blocks", "seed", "tc_type", "max_channels", "reference",
                "fill_first")


@dataclass(frozen=True)
class TrainOptions:
    """How ``train_model`` trains (its keywords; docs/training.md), each constraint beside it
    and checked by ``check``."""

    sensors: str | tuple[str, ...] = "T*"  # a glob, or the names
    aux: tuple[str, ...] = ()
    max_sensors: int = DEFAULT_MAX_SENSORS  # at most max_channels
    groups: int = DEFAULT_GROUPS
    effects: bool = True
    ambient: str | None = None
    channels: Mapping[str, int] | None = None  # sensor -> box channel (record.box_channels)
    selection: str = "validated"  # one of host.selection.METHODS
    max_delay_s: float | None = None
    n_blocks: int = DEFAULT_BLOCKS  # at least 2
    seed: int = 0
    fill_gaps: int = 0
    tc_type: str = DEFAULT_TC_TYPE  # one of TC_TYPES
    max_channels: int = BOX_CHANNELS  # 1..BOX_CHANNELS
    reference: str = DEFAULT_REFERENCE
    fit: str = DEFAULT_FIT  # one of nested.FITS
    nested: bool = True
    fill_channels: bool = True
    tilts: tuple[Tilt, ...] = ()  # each a target
    fill_first: bool | None = None  # None: with several axes when the ridge reads the fill
    bending: tuple[str, ...] = ()  # each a target; only a ridge has the penalty
    prefilter_s: float = PREFILTER_TAU_S  # 0 (off) or a time constant, finite
    jobs: int | None = None  # None or a number of processes, 1 or more
    quiet: bool = True

    @staticmethod
    def of(**options) -> TrainOptions:
        """The options from ``train_model``'s keywords (sequences kept as tuples; an unknown
        keyword is a TypeError, as a function's would be)."""
        known = {f.name for f in fields(TrainOptions)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise TypeError(f"train_model() got an unexpected keyword argument '{unknown[0]}'")
        for name in ("aux", "tilts", "bending"):
            if name in options:
                options[name] = tuple(options[name] or ())
        if not isinstance(options.get("sensors", "T*"), str):
            options["sensors"] = tuple(options["sensors"])
        return TrainOptions(**options)

    def for_fold(self, sensors: Sequence[str], fill_first: bool) -> TrainOptions:
        """The options a nested fold trains with: this model's ``FOLD_OPTIONS`` on the
        sensors it read, one axis by least squares, without nested validation of its own
        (a fold of one axis fills as this model did: ``fill_first``)."""
        kept = {name: getattr(self, name) for name in FOLD_OPTIONS}
        return replace(TrainOptions(**kept), sensors=tuple(sensors), fill_first=fill_first,
                       fit="ols", nested=False)

    def check(self, targets: Sequence[str]) -> None:
        """Refuse inconsistent options before any data is read, each with its reason."""
        if not targets:
            raise TrainingError("give at least one --target")
        if len(set(targets)) != len(targets):
            raise TrainingError(f"a target is given twice: {list(targets)}")
        if self.fit not in FITS:
            raise InputError(f"--fit must be one of {', '.join(FITS)} (got {self.fit!r})")
        if self.selection not in METHODS:
            raise TrainingError(f"unknown --selection '{self.selection}' (known: "
                                f"{', '.join(METHODS)})")
        if self.n_blocks < 2:
            raise TrainingError(f"need at least 2 validation blocks (got {self.n_blocks})")
        self._check_box(targets)
        if not (math.isfinite(self.prefilter_s) and self.prefilter_s >= 0):
            raise TrainingError(f"--prefilter-s must be 0 (off) or a time constant in seconds "
                                f"(got {self.prefilter_s})")
        jobs = self.jobs
        if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int)
                                 or jobs < 1):
            raise TrainingError(f"--jobs must be a number of processes, 1 or more (got "
                                f"{jobs!r})")
        if self.bending and (self.fit == "ols" or (self.fit == "auto" and not self.nested)):
            raise TrainingError("--bending shapes the ridge's penalty; least squares has none "
                                "(--fit ols, or --fit auto with --no-nested: use --fit ridge)")

    def _check_box(self, targets: Sequence[str]) -> None:
        """The box's budget and wiring, and the axes named by --tilt and --bending."""
        if not 1 <= self.max_channels <= BOX_CHANNELS:
            raise TrainingError(f"--max-channels must be 1..{BOX_CHANNELS} (the box has "
                                f"{BOX_CHANNELS} thermocouple inputs), got {self.max_channels}")
        if self.max_sensors > self.max_channels:
            raise TrainingError(f"--max-sensors {self.max_sensors} exceeds --max-channels "
                                f"{self.max_channels}")
        if self.tc_type not in TC_TYPES:
            raise TrainingError(f"thermocouple type must be K or J (got {self.tc_type!r})")
        for option, names in (("--tilt", [t.name for t in self.tilts]),
                              ("--bending", self.bending)):
            for name in names:
                if name not in targets:
                    raise TrainingError(f"{option} {name}: not among the targets "
                                        f"({', '.join(targets)})")
