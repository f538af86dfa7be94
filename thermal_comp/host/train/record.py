"""The model.json record `host train` writes: the box's inputs and axes, and how it was trained
(docs/model-json.md); the one place its top-level keys are put together."""

from __future__ import annotations

from collections.abc import Sequence

from thermal_comp.contract import __version__
from thermal_comp.contract.model_file import SCHEMA
from thermal_comp.contract.tilt import Tilt
from thermal_comp.host.train.training_data import TrainingData

TIME_MAX_S = 604800.0  # one week of `time` term before it saturates


def model_json(data: TrainingData, axes: dict[str, dict], wired: list, aux_inputs: list,
                tilts: Sequence[Tilt], training: dict) -> dict:
    """The model.json dict: the box's inputs and axes, and how it was trained."""
    return {
        "schema": SCHEMA,
        "tool_version": __version__,
        "sample_period_s": float(data.period_s),
        "reference": data.ref.to_json(),
        "channels": wired,
        "aux": aux_inputs,
        "time_max_s": TIME_MAX_S,
        "axes": axes,
        **({"tilts": [t.to_json() for t in tilts]} if tilts else {}),
        "training": {"runs": [r.path for r in data.runs], **training},
    }
