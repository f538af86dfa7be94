"""The reference of a correction: what "zero drift" means on a given day.

A thermal test starts with the probes zeroed (ISO 230-3), and on the machine the correction
that matters is the drift since the tool and work offsets were taken. With the ``start``
reference a model predicts the change since the start of each run (on the box: since power-up
or the last ``ZERO``), so a day that starts warmer than the training day is no offset; with
``none`` it predicts absolute values against one fixed datum (a continuous recording such as
FL_THERMAL).

The reference must not rest on one noisy sample: it is the mean of the first ``samples``
samples of the series (the box's ``BOX_ZERO_SAMPLES``, contract.box.ZERO_SAMPLES, so host and
box reference alike), taken causally as the box does after ZERO: at sample i < samples it is
the mean of samples 0..i (so the first output is exactly 0), then it is frozen. The same rule
applies to the measured displacement and to the prediction, so it cancels wherever the model
tracks; docs/training.md has the measurement.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from thermal_comp.contract.box import ZERO_SAMPLES
from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import ModelSpec, spec_of

KINDS = ("start", "none")


def _running_head(values: np.ndarray, samples: int) -> np.ndarray:
    """The running mean of each of the first min(samples, n) rows (n >= 1)."""
    k = min(samples, values.shape[0])
    counts = np.arange(1, k + 1, dtype=float).reshape((k,) + (1,) * (values.ndim - 1))
    return np.cumsum(values[:k], axis=0) / counts


def causal_reference(values: np.ndarray, samples: int) -> np.ndarray:
    """Per row, the running mean of the first ``samples`` rows (frozen after them); 1-D or 2-D."""
    values = np.asarray(values, dtype=float)
    if values.shape[0] == 0:
        return values.copy()
    head = _running_head(values, samples)
    out = np.empty_like(values)
    out[:len(head)] = head
    out[len(head):] = head[-1]
    return out


def _subtract_reference(view: np.ndarray, samples: int) -> None:
    """``view`` minus causal_reference(view, samples), in place (the same arithmetic)."""
    if view.shape[0] == 0:
        return
    head = _running_head(view, samples)
    view[len(head):] -= head[-1]
    view[:len(head)] -= head


@dataclass(frozen=True)
class Reference:
    """How a model's output is referenced (stored in model.json as ``reference``)."""

    kind: str = "none"
    samples: int = 1

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise InputError(f"--reference must be one of {', '.join(KINDS)} (got {self.kind!r})")
        if self.samples < 1:
            raise InputError(f"reference samples must be >= 1 (got {self.samples})")

    @staticmethod
    def of_kind(kind: str) -> Reference:
        """``start`` over the box's ZERO window (whatever the sample period), or ``none``."""
        return Reference(kind, ZERO_SAMPLES if kind == "start" else 1)

    @staticmethod
    def of_model(model: Mapping | ModelSpec) -> Reference:
        """The model's reference (its typed view's; a model written before references were
        kept has ``none``)."""
        ref = spec_of(model).reference
        return Reference(ref.kind, ref.samples)

    def to_json(self) -> dict:
        out: dict = {"kind": self.kind}
        if self.kind == "start":
            out.update(samples=self.samples)
        return out

    def apply(self, values: np.ndarray, segments: np.ndarray | None = None) -> np.ndarray:
        """``values`` minus their reference, each segment (run, or fold of a run) on its own."""
        values = np.asarray(values, dtype=float)
        if self.kind == "none":
            return values
        out = values.copy()  # referenced in place: a day of 1-s rows is a large array
        for start, stop in ([(0, len(out))] if segments is None else segment_bounds(segments)):
            _subtract_reference(out[start:stop], self.samples)
        return out


NO_REFERENCE = Reference()


def segment_bounds(labels: np.ndarray) -> list[tuple[int, int]]:
    """Contiguous runs of equal labels as (start, stop) row ranges."""
    labels = np.asarray(labels)
    if labels.size == 0:
        return []
    cuts = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    edges = [0, *cuts.tolist(), labels.size]
    return list(zip(edges[:-1], edges[1:], strict=True))
