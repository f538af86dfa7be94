"""Stage 1 of codegen: model.json dict (or its typed view) -> validated, quantised ``QModel``.

Checking model.json (``contract.model_file.check_model``, which gives the typed view) comes
first; each check left here guards a number that is quantised next to it, in the order of
docs/fixed-point.md: the inputs in ``quantise_inputs``, the axes in ``quantise_axes``, the
result's types in ``qmodel`` (re-exported here).

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
from thermal_comp.codegen.quantise_inputs import parse_aux, parse_channels, parse_period
from thermal_comp.contract.fixed_point import INT32_MAX
from thermal_comp.contract.model_file import SCHEMA, ModelFormatError, ModelSpec, spec_of

__all__ = [  # the stage and the types it makes, wherever each lives
    "COEF_UNIT", "DEFAULT_MAX_C", "DEFAULT_MIN_C", "MAX_AUX", "MAX_AXES", "MAX_CHANNELS",
    "MAX_STATES", "MAX_TERMS_PER_AXIS", "X_UNIT_TEXT", "QAux", "QAxis", "QChannel", "QModel",
    "QTerm", "quantise",
]


def quantise(model: Mapping | ModelSpec) -> QModel:
    """Validate a model (model.json dict, or its typed view) and quantise it (raises
    CodegenError naming the problem).

    The structural checks are ``contract.model_file.check_model``'s (the same for every
    command; the typed view it returns is what is quantised); what follows adds only what
    needs the fixed-point encoding.
    """
    spec = checked_spec(model)
    period_s = spec.sample_period_s
    period_ms = parse_period(period_s)
    channels = parse_channels(spec.channels, period_s)
    aux = parse_aux(spec.aux)
    time_max_s = spec.time_max_s
    time_max_samples = None
    if time_max_s is not None:
        time_max_samples = math.floor(Fraction(time_max_s) / Fraction(period_s))
        if not 0 <= time_max_samples <= INT32_MAX:
            raise CodegenError(f"time_max_s: {time_max_s!r} s is {time_max_samples} samples; "
                               f"it must be within 0..{INT32_MAX} samples")
    start = spec.reference.kind == "start"
    axes = [with_service(parse_axis(i, ax, channels, aux, period_s, time_max_samples),
                         ax.service, period_s, start)
            for i, ax in enumerate(spec.axes)]
    return QModel(SCHEMA, spec.model_hash, period_s, period_ms, time_max_s,
                  time_max_samples, channels, aux, number_states(axes))


def checked_spec(model: Mapping | ModelSpec) -> ModelSpec:
    """The model's typed view (``contract.model_file.spec_of``), its refusals as CodegenError."""
    try:  # the structural rules every command shares (contract.model_file)
        return spec_of(model, "")
    except ModelFormatError as exc:
        raise CodegenError(str(exc)) from None
