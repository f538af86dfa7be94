"""Stage 1 of codegen: model.json dict -> validated, already-quantised ``QModel``.

Validating model.json and quantising it are one pass (each check guards a number that is
quantised next to it), in the order of docs/fixed-point.md: the inputs in ``quantise_inputs``,
the axes in ``quantise_axes``, the result's types in ``qmodel`` (re-exported here).

Everything numeric the header, the CRC, the error bound and the Python twin need is decided
here, in exact rational arithmetic (``fractions.Fraction``), so that rendering is pure
formatting and the twin evaluates exactly the tables the firmware gets. The rules are
docs/fixed-point.md; the choices it leaves open are docs/codegen.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from fractions import Fraction

from thermal_comp.codegen.errors import CodegenError
from thermal_comp.codegen.qmodel import (
    COEF_UNIT,
    DEFAULT_MAX_C,
    DEFAULT_MIN_C,
    MAX_AUX,
    MAX_AXES,
    MAX_CHANNELS,
    MAX_STATES,
    MAX_TERMS_PER_AXIS,
    X_UNIT_TEXT,
    QAux,
    QAxis,
    QChannel,
    QModel,
    QTerm,
)
from thermal_comp.codegen.quantise_axes import number_states, parse_axis, with_service
from thermal_comp.codegen.quantise_inputs import number, parse_aux, parse_channels, parse_period
from thermal_comp.contract.fixed_point import INT32_MAX
from thermal_comp.contract.model_file import SCHEMA, ModelFormatError, check_model

__all__ = [  # the stage and the types it makes, wherever each lives
    "COEF_UNIT", "DEFAULT_MAX_C", "DEFAULT_MIN_C", "MAX_AUX", "MAX_AXES", "MAX_CHANNELS",
    "MAX_STATES", "MAX_TERMS_PER_AXIS", "X_UNIT_TEXT", "QAux", "QAxis", "QChannel", "QModel",
    "QTerm", "quantise",
]


def quantise(model: Mapping) -> QModel:
    """Validate a model.json dict and quantise it (raises CodegenError naming the problem).

    The structural checks are ``contract.model_file.check_model``'s (the same for every
    command); what follows adds only what needs the fixed-point encoding.
    """
    from thermal_comp.codegen.hashing import model_hash

    try:  # the structural rules every command shares (contract.model_file)
        check_model(model, "", output_range=False)
    except ModelFormatError as exc:
        raise CodegenError(str(exc)) from None
    schema = model.get("schema")
    if schema != SCHEMA:
        raise CodegenError(f"schema {schema!r} is not supported (expected {SCHEMA!r})")
    period_s, period_ms = parse_period(model)
    channels = parse_channels(model, period_s)
    aux = parse_aux(model)
    time_max_s = model.get("time_max_s")
    time_max_samples = None
    if time_max_s is not None:
        time_max_s = number(time_max_s, "time_max_s")
        time_max_samples = math.floor(Fraction(time_max_s) / Fraction(period_s))
        if not 0 <= time_max_samples <= INT32_MAX:
            raise CodegenError(f"time_max_s: {time_max_s!r} s is {time_max_samples} samples; "
                               f"it must be within 0..{INT32_MAX} samples")
    axes_raw = model.get("axes")
    if not isinstance(axes_raw, Mapping) or not axes_raw:
        raise CodegenError("axes: the model has no axes")
    if len(axes_raw) > MAX_AXES:
        raise CodegenError(f"axes: {len(axes_raw)} axes exceed the runtime's {MAX_AXES}")
    axes = [parse_axis(i, name, ax, channels, aux, period_s, time_max_samples)
            for i, (name, ax) in enumerate(axes_raw.items())]
    start = (model.get("reference") or {}).get("kind", "none") == "start"
    axes = [with_service(ax, axes_raw[ax.name], period_s, start) for ax in axes]
    return QModel(SCHEMA, model_hash(model), period_s, period_ms, time_max_s,
                  time_max_samples, channels, aux, number_states(axes))
