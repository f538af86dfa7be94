"""The training runs as every step of ``host train`` sees them (host.train.pipeline).

Temperatures and targets stacked and referenced once (the change since each run's start with
the ``start`` reference), the validation folds, and the sensors that carry no signal; the
selection and the channel budget's cost both work on this one view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.terms import Term, make_temp
from thermal_comp.host.fitting import Reference, common_period, fold_groups, stack, validation_rmse
from thermal_comp.host.io import Run, check_variation
from thermal_comp.host.selection import select_sensors


class TrainingError(InputError):
    """Training inputs are inconsistent (unknown target, bad channel map, ...)."""


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

    def select(self, target: str, pool: list[str] | None = None, **choose
               ) -> tuple[list[Term], dict]:
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
        return [make_temp(pool_names[i]) for i in result.sensors], result.trace(pool_names)

    def done_selecting(self) -> None:
        """Free the stacked temperatures only the selection reads (a day of 64 sensors at 1 s
        is 44 MB, held through the effects and the next-day fits otherwise)."""
        self.X = None

    def vrmse(self, target: str, terms: list[Term]) -> float:
        """Out-of-fold RMSE of ``terms`` fitted on ``target`` (the budget's cost)."""
        st = stack(self.runs, terms, target, self.period_s, self.n_blocks, self.ref)
        return validation_rmse(st.X, st.y, st.groups)


