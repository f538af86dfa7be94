"""A recorded run turned into what the box's inputs would have seen.

Temperatures become MAX31856 linearised-register codes (1/128 degC, 19-bit) with the twin's
own conversion (``codegen.fixed.temp_to_code``), so the chip quantisation the firmware sees
is exactly the one the host evaluates; the aux input (spindle speed) becomes whole rpm, as the
box's ADC path delivers it. Which run column feeds which channel comes from model.json.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import ModelSpec, spec_of
from thermal_comp.contract.tilt import available_axes
from thermal_comp.host.fitting import NO_REFERENCE, Reference
from thermal_comp.host.io import Run, load_run


class FeedError(InputError):
    """The run cannot be replayed with this model (names the file and the column)."""


@dataclass
class Feed:
    """Per-sample inputs of the box for one run, in the model's channel/aux order."""

    run: Run
    codes: np.ndarray  # (n, n_channels) int64, 1/128 degC
    aux: np.ndarray  # (n, n_aux) int64, aux unit (rpm)
    axes: list[str]  # model axes, in model order
    measured: dict[str, np.ndarray]  # axis -> measured displacement (um), axes the run has
    reference: Reference = NO_REFERENCE  # the model's: how measured and box output are judged

    @property
    def n_samples(self) -> int:
        return int(self.codes.shape[0])

    def feed_lines(self, codes: np.ndarray | None = None) -> list[bytes]:
        """The native board's ``S`` feed command per sample (docs/native-board.md).

        ``codes`` replaces the run's codes (fault scenarios override some of them).
        """
        c = self.codes if codes is None else codes
        aux0 = self.aux[:, 0] if self.aux.shape[1] else np.zeros(self.n_samples, np.int64)
        table = np.column_stack([aux0, c]).astype(np.int64).tolist()
        return [("S " + " ".join(map(str, row)) + "\n").encode("ascii") for row in table]


def _header(path: Path) -> list[str]:
    if not path.is_file():
        raise FeedError(f"{path}: run file not found")
    with path.open(newline="", encoding="utf-8-sig") as fh:
        return [h.strip() for h in next(csv.reader(fh), [])]


def build_feed(model: Mapping | ModelSpec, data_path: str | Path, reference: str | None = None,
               max_aux: int = 1) -> Feed:
    """Load ``data_path`` with the model's sensors/aux/axes and quantise it like the box does;
    judged with ``reference`` (``start``/``none``), by default the model's own. ``model``: the
    typed view (``ModelBuild.spec``), or the dict."""
    from thermal_comp.codegen.fixed import temp_to_code

    model = spec_of(model)
    path = Path(data_path)
    header = _header(path)
    sensors = model.sensors
    aux = model.aux_names
    if len(aux) > max_aux:
        raise FeedError(f"model uses {len(aux)} aux inputs ({', '.join(aux)}); the feed "
                        f"carries {max_aux}")
    for name in [*sensors, *aux]:
        if name not in header:
            raise FeedError(f"{path}, line 1, column '{name}': the model needs this column "
                            f"but the run does not have it")
    axes = model.axis_names
    tilts = list(model.tilts)
    targets = available_axes(header, axes, tilts)
    run = load_run(path, targets=targets, sensors=sensors, aux=aux, tilts=tilts)
    period = model.sample_period_s
    if abs(run.period_s - period) > 1e-6 * max(1.0, period):
        raise FeedError(f"{path}: the run is sampled every {run.period_s:g} s but the model "
                        f"(and the box) every {period:g} s")
    codes = np.asarray(temp_to_code(run.temperatures), dtype=np.int64).reshape(
        run.n_samples, len(sensors))
    aux_values = (np.rint(run.aux).astype(np.int64) if run.aux is not None
                  else np.zeros((run.n_samples, 0), dtype=np.int64))
    # judged as the model is (or as asked): with ``start``, the change since the run's start
    ref = Reference.of_kind(reference) if reference is not None else Reference.of_model(model)
    measured = {a: ref.apply(run.target(a)) for a in targets}
    return Feed(run, codes, aux_values, axes, measured, ref)
