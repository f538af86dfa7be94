"""A loaded thermal test run: the columns split by role (time, temperatures, displacements,
aux), so every later step asks for a role, not a column of the file."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from thermal_comp.contract.errors import MissingColumnError

TIME_COLUMN = "time_s"


@dataclass
class Run:
    """One thermal test run, columns already split by role."""

    path: str
    time_s: np.ndarray
    sensor_names: list[str]
    temperatures: np.ndarray  # (n_samples, n_sensors), degC
    target_names: list[str]
    displacements: np.ndarray  # (n_samples, n_targets), um
    aux_names: list[str] = field(default_factory=list)
    aux: np.ndarray | None = None  # (n_samples, n_aux)
    filled_cells: int = 0
    piece: bool = False  # cut out of one run for validation (slice): the same day as the rest

    @property
    def n_samples(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def name(self) -> str:
        return Path(self.path).stem

    @property
    def period_s(self) -> float:
        """Median sample period; models with dynamic terms assume this fixed period."""
        return float(np.median(np.diff(self.time_s)))

    def column(self, name: str) -> np.ndarray:
        """Any column by name (sensor, target, aux or time_s)."""
        if name == TIME_COLUMN:
            return self.time_s
        for names, data in ((self.sensor_names, self.temperatures),
                            (self.target_names, self.displacements),
                            (self.aux_names, self.aux)):
            if name in names and data is not None:
                return data[:, names.index(name)]
        raise MissingColumnError(f"{self.path}: no column '{name}'")

    def columns(self) -> dict[str, np.ndarray]:
        """All columns by name, for term evaluation (see contract.terms)."""
        out = {TIME_COLUMN: self.time_s}
        out.update({n: self.temperatures[:, i] for i, n in enumerate(self.sensor_names)})
        out.update({n: self.displacements[:, i] for i, n in enumerate(self.target_names)})
        if self.aux is not None:
            out.update({n: self.aux[:, i] for i, n in enumerate(self.aux_names)})
        return out

    def target(self, name: str) -> np.ndarray:
        return self.displacements[:, self.target_names.index(name)]

    def every(self, step: int) -> Run:
        """Every ``step``-th sample (its period ``step`` times longer), for a quick screening."""
        if step <= 1:
            return self
        return Run(self.path + f"[::{step}]", self.time_s[::step], list(self.sensor_names),
                   self.temperatures[::step], list(self.target_names),
                   self.displacements[::step], list(self.aux_names),
                   None if self.aux is None else self.aux[::step], piece=self.piece)

    def slice(self, start: int, stop: int) -> Run:
        """A contiguous part of the run (for time-blocked validation)."""
        return Run(self.path + f"[{start}:{stop}]", self.time_s[start:stop],
                   list(self.sensor_names), self.temperatures[start:stop], list(self.target_names),
                   self.displacements[start:stop], list(self.aux_names),
                   None if self.aux is None else self.aux[start:stop], piece=True)
