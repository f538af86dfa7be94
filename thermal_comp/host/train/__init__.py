"""The training pipeline: selection, the channel budget, effects, one refit; the model dict.
"""

from __future__ import annotations

from thermal_comp.host.train.nested import DEFAULT_FIT, FITS
from thermal_comp.host.train.options import DEFAULT_REFERENCE, TrainOptions
from thermal_comp.host.train.pipeline import train_model
from thermal_comp.host.train.ranges import (
    TOLERANCE_SHARE,
    describe,
    input_units,
    outside_training,
    training_ranges,
)
from thermal_comp.host.train.searched import axis_with_effects
from thermal_comp.host.train.summary import (
    axis_sensors,
    box_effects_evidence,
    box_model_note,
    dropped_reason,
    ridge_lags_note,
    summary,
)
from thermal_comp.host.train.training_data import TrainingError

__all__ = [
    "box_effects_evidence",
    "box_model_note",
    "dropped_reason",
    "ridge_lags_note",
    "DEFAULT_FIT",
    "FITS",
    "DEFAULT_REFERENCE",
    "TOLERANCE_SHARE",
    "TrainOptions",
    "TrainingError",
    "axis_sensors",
    "axis_with_effects",
    "describe",
    "input_units",
    "outside_training",
    "summary",
    "train_model",
    "training_ranges",
]
