"""Validation on data the fit did not see: leave-one-run-out, or time blocks of one run.

Features are always computed on each whole run first (lag filters run causally from the run's
start, as on the box) and only then split into folds, so a fold's test rows carry the same
filter states the box would have. Folds are given as a group label per stacked sample:
- several runs: each run is a group (leave-one-run-out);
- one run: the run is cut into ``n_blocks`` contiguous time blocks (default 3), each a group;
  a fold trains on the other blocks and tests on its own. Contiguous blocks keep the strong
  autocorrelation of thermal data from leaking between train and test the way a random split
  would.
The fits themselves (and their out-of-fold errors) are host.fitting.out_of_fold's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contract.errors import InputError
from contract.terms import Term
from host.fitting.features import design_matrix
from host.fitting.reference import NO_REFERENCE, Reference
from host.io import Run

DEFAULT_BLOCKS = 3


@dataclass
class Stacked:
    """Design matrix, target and fold labels of several runs stacked row-wise."""

    X: np.ndarray
    y: np.ndarray
    groups: np.ndarray
    scheme: str  # human-readable description of the validation scheme

    @property
    def n_folds(self) -> int:
        return int(np.unique(self.groups).size)


def fold_groups(runs: list[Run], n_blocks: int = DEFAULT_BLOCKS) -> tuple[np.ndarray, str]:
    """Group label per stacked sample and the scheme's description."""
    if len(runs) >= 2:
        groups = np.concatenate([np.full(r.n_samples, i) for i, r in enumerate(runs)])
        return groups, f"leave-one-run-out ({len(runs)} runs)"
    n = runs[0].n_samples
    groups = np.minimum((np.arange(n) * n_blocks) // n, n_blocks - 1)
    return groups, f"time-blocked ({n_blocks} contiguous blocks of one run)"


def common_period(runs: list[Run], tolerance: float = 0.01) -> float:
    """The sample period all runs share (dynamic terms assume one fixed period)."""
    periods = [r.period_s for r in runs]
    p0 = periods[0]
    for run, p in zip(runs, periods, strict=True):
        if abs(p - p0) > tolerance * p0:
            raise InputError(f"{run.path}: sample period {p:g} s differs from {runs[0].path} "
                             f"({p0:g} s); resample the runs to one period")
    return p0


def run_labels(runs: list[Run]) -> np.ndarray:
    """Run index per stacked sample (a reference restarts at each run's start)."""
    return np.concatenate([np.full(r.n_samples, i) for i, r in enumerate(runs)])


def stack(runs: list[Run], terms: list[Term], target: str, period_s: float,
          n_blocks: int = DEFAULT_BLOCKS, reference: Reference = NO_REFERENCE) -> Stacked:
    """Evaluate the terms on each run and stack runs with their fold labels.

    With a ``start`` reference every run is referenced at its own start, features and target
    alike, so a held-out run is scored as the unseen day it stands for. A time block of one run
    is not a new day (nothing was zeroed when it began): it keeps the run's reference.
    """
    X = np.vstack([design_matrix(terms, r.columns(), period_s) for r in runs])
    y = np.concatenate([r.target(target) for r in runs])
    groups, scheme = fold_groups(runs, n_blocks)
    per_run = run_labels(runs)
    return Stacked(reference.apply(X, per_run), reference.apply(y, per_run), groups, scheme)
