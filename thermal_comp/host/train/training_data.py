"""The training runs as every step of ``host train`` sees them (host.train.pipeline).

The runs are loaded (or, given loaded, restricted to the requested sensors) once: as_runs.

Temperatures and targets stacked and referenced once (the change since each run's start with
the ``start`` reference), the validation folds, and the sensors that carry no signal; the
selection and the channel budget's cost both work on this one view.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.terms import Term, make_temp
from thermal_comp.contract.tilt import Tilt
from thermal_comp.host.fitting import Reference, common_period, fold_groups, stack, validation_rmse
from thermal_comp.host.io import Run, check_variation, load_runs, missing_sensors
from thermal_comp.host.selection import select_sensors


class TrainingError(InputError):
    """Training inputs are inconsistent (unknown target, bad channel map, ...)."""


class Selected(NamedTuple):
    """One axis's selection: its terms, and the selection's trace (model.json ``selection``)."""

    terms: list[Term]
    trace: dict


Selections = dict[str, Selected]  # every axis's selection, by target


@dataclass
class TrainingData:
    """The training runs as every step sees them: temperatures and targets stacked and
    referenced (the change since each run's start with ``start``), with the folds."""

    runs: list[Run]
    names: list[str]
    period_s: float
    ref: Reference
    n_blocks: int
    X: np.ndarray | None  # None once done_selecting
    ys: dict[str, np.ndarray]
    run_ids: np.ndarray
    folds: np.ndarray  # the selection's folds (a single run's blocks follow its phases)
    folds_scheme: str
    scheme: str  # the validation of the fits (equal blocks of a single run)
    dead: set[int]  # sensors constant in every run (dead or stuck): they carry no signal

    @staticmethod
    def of(runs: list[Run], targets: list[str], n_blocks: int, ref: Reference) -> TrainingData:
        check_variation(runs, targets)
        period_s = common_period(runs)
        n_min = min(r.n_samples for r in runs)
        if len(runs) == 1 and n_min < 2 * n_blocks:
            raise TrainingError(f"{runs[0].path}: {n_min} samples is too few for {n_blocks} "
                                "validation blocks")
        run_ids = np.concatenate([np.full(r.n_samples, i) for i, r in enumerate(runs)])
        folds, folds_scheme = fold_groups(runs, n_blocks, phases=True)
        scheme = fold_groups(runs, n_blocks)[1]
        # selection sees what the model will: the change since the start
        X = ref.apply(np.vstack([r.temperatures for r in runs]), run_ids)
        ys = {t: ref.apply(np.concatenate([r.target(t) for r in runs]), run_ids)
              for t in targets}
        dead = {i for i in range(X.shape[1]) if not np.ptp(X[:, i]) > 0}
        return TrainingData(runs, list(runs[0].sensor_names), period_s, ref, n_blocks, X, ys,
                            run_ids, folds, folds_scheme, scheme, dead)

    @property
    def pool(self) -> list[str]:
        """The sensors that carry a signal."""
        return [n for i, n in enumerate(self.names) if i not in self.dead]

    def select(self, target: str, pool: list[str] | None = None, **choose) -> Selected:
        """host.selection on the live sensors of ``pool`` (default all): terms and trace."""
        if self.X is None:
            raise AssertionError("select() after done_selecting()")
        cols = [self.names.index(n) for n in (self.names if pool is None else pool)]
        cols = [i for i in cols if i not in self.dead]
        result = select_sensors(self.X[:, cols], self.ys[target], self.run_ids, self.folds,
                                self.period_s, n_groups=choose["groups"],
                                max_sensors=choose["max_sensors"], method=choose["selection"],
                                max_delay_s=choose["max_delay_s"], seed=choose["seed"],
                                scheme=self.folds_scheme)
        pool_names = [self.names[i] for i in cols]
        return Selected([make_temp(pool_names[i]) for i in result.sensors],
                        result.trace(pool_names))

    def done_selecting(self) -> None:
        """Free the stacked temperatures only the selection reads (a day of 64 sensors at 1 s
        is 44 MB, held through the effects and the next-day fits otherwise)."""
        self.X = None

    def vrmse(self, target: str, terms: list[Term]) -> float:
        """Out-of-fold RMSE of ``terms`` fitted on ``target`` (the budget's cost)."""
        st = stack(self.runs, terms, target, self.period_s, self.n_blocks, self.ref)
        return validation_rmse(st.X, st.y, st.groups)


def _sensor_columns(temperatures: np.ndarray, idx: list[int]) -> np.ndarray:
    """``temperatures[:, idx]``: a copy, column-major (numpy lays out a gather along the
    second axis so, and every later sum over a run follows that layout). Already
    column-major with every column in order (``host train`` hands its runs so), the array is
    that copy's twin and is used as it is: 44 MB less for 64 sensors x 86,400 rows."""
    if (temperatures.ndim == 2 and temperatures.shape[1] >= 2
            and temperatures.flags.f_contiguous and idx == list(range(temperatures.shape[1]))):
        return temperatures
    return temperatures[:, idx]


def as_runs(runs: Sequence[Run | str | Path], targets: list[str], sensors: str | list[str],
            aux: list[str], fill_gaps: int, tilts: Sequence[Tilt] = ()) -> list[Run]:
    """Load paths (tilt targets computed from their probes); restrict already-loaded runs to
    the requested sensors."""
    if not runs:
        raise TrainingError("no training runs given")
    if all(isinstance(r, (str, Path)) for r in runs):
        return load_runs(list(runs), targets, sensors, aux, fill_gaps, min_samples=4,
                         tilts=tilts)
    out = []
    for run in runs:
        if not isinstance(run, Run):
            raise TrainingError("runs must be all paths or all host.io.Run objects")
        for t in targets:
            if t not in run.target_names:
                raise TrainingError(f"{run.path}: no target column '{t}'")
        if isinstance(sensors, str):
            names = [n for n in run.sensor_names if fnmatch.fnmatchcase(n, sensors)]
        else:
            names = list(sensors)
        missing = [n for n in names if n not in run.sensor_names]
        if missing:
            raise TrainingError(f"{run.path}: " + missing_sensors(missing, run.sensor_names,
                                                                   "given by sensors"))
        if not names:
            raise TrainingError(f"{run.path}: no sensor column matches {sensors!r}; the run's "
                                f"columns: {', '.join(run.sensor_names)}")
        idx = [run.sensor_names.index(n) for n in names]
        out.append(Run(run.path, run.time_s, names, _sensor_columns(run.temperatures, idx),
                       list(run.target_names), run.displacements, list(run.aux_names), run.aux,
                       run.filled_cells))
    first = out[0].sensor_names
    for run in out[1:]:
        if run.sensor_names != first:
            raise TrainingError(f"{run.path}: sensor columns differ from {out[0].path}")
    return out
