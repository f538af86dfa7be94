"""The quantised model: every number the header, the CRC, the bound and the twin read.

Decided once by ``quantise`` in exact arithmetic, then only formatted (render), serialised
(crc), bounded (bound) and evaluated (fixed), so all four agree on the same tables.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from fractions import Fraction

from thermal_comp.codegen.estimator import FixedParams
from thermal_comp.contract.box import (
    CHANNEL_MAX_C,
    CHANNEL_MIN_C,
    RUNTIME_MAX_AUX,
    RUNTIME_MAX_AXES,
    RUNTIME_MAX_CHANNELS,
    RUNTIME_MAX_STATES,
    RUNTIME_MAX_TERMS_PER_AXIS,
)
from thermal_comp.contract.terms import FILTER_KINDS

# Runtime capacity (firmware/include/model_eval.h), named as codegen's messages use them.
MAX_CHANNELS = RUNTIME_MAX_CHANNELS
MAX_AUX = RUNTIME_MAX_AUX
MAX_AXES = RUNTIME_MAX_AXES
MAX_STATES = RUNTIME_MAX_STATES
MAX_TERMS_PER_AXIS = RUNTIME_MAX_TERMS_PER_AXIS
DEFAULT_MIN_C = CHANNEL_MIN_C
DEFAULT_MAX_C = CHANNEL_MAX_C

COEF_UNIT = {"temp": "um/degC", "lag": "um/degC", "rate": "um/degC", "speed": "um/rpm",
             "speed2": "um/rpm^2", "square": "um/degC^2", "time": "um/s"}
X_UNIT_TEXT = {"temp": "1/128 degC", "lag": "2^-23 degC", "rate": "2^-23 degC",
               "speed": "rpm", "speed2": "rpm^2", "square": "2^-14 degC^2",
               "time": "sample periods"}


@dataclass(frozen=True)
class QChannel:
    index: int
    sensor: str
    tc_type: str
    tc_code: int
    min_c: float
    max_c: float
    min_code: int
    max_code: int
    window_lo_code: int  # training range widened by EXTRAPOLATION_MARGIN, in codes; the
    window_hi_code: int  # valid range when the model has no training range for the channel
    max_step_code: int = 1  # largest plausible change per sample (codes, >= 1): IMPLAUSIBLE
    max_step_source: str = "model"  # "model" (max_step_c) or "default" (older model.json)
    max_still_samples: int = 0  # same code this many samples in a row: STUCK (0: no check)


@dataclass(frozen=True)
class QAux:
    index: int
    name: str
    min_value: float
    max_value: float
    min: int
    max: int


@dataclass(frozen=True)
class QTerm:
    """One quantised term. ``c`` is the exact real coefficient in nm per unit of x_j."""

    position: int  # index within its axis
    kind: str
    kind_code: int
    source: str | None
    input: int  # channel or aux index (0 for time)
    param: int  # a, ref_code, time_max_samples or 0
    state: int | None  # filter state index (lag/rate; shared by equal input and a)
    coef_um: float
    c: Fraction
    coef_q: int
    xmax: int  # max |x_j| over the declared input ranges
    label: str
    params: Mapping[str, float]

    @property
    def coef_unit(self) -> str:
        return COEF_UNIT[self.kind]


@dataclass(frozen=True)
class QAxis:
    index: int
    name: str
    unit: str
    intercept_um: float
    c0: Fraction  # exact intercept in nm
    shift: int
    intercept_q: int
    terms: tuple[QTerm, ...]
    acc_max: int  # |intercept_q| + sum |coef_q| * max(xmax, 1)
    out_max_nm: int  # rdiv(acc_max, shift)
    max_step_nm: int = 1  # the output never steps more than this per sample (nm, >= 1)
    max_step_source: str = "model"  # "model" (max_step_um) or "default" (older model.json)
    # the in-service estimator's parameters (codegen.estimator.FixedParams) from the axis's
    # service block; None: the model has none and the box refuses MEAS for the axis (OFF)
    service: FixedParams | None = None


@dataclass(frozen=True)
class QModel:
    schema: str
    model_hash: str
    period_s: float
    period_ms: int
    time_max_s: float | None
    time_max_samples: int | None
    channels: tuple[QChannel, ...]
    aux: tuple[QAux, ...]
    axes: tuple[QAxis, ...]

    @property
    def n_terms(self) -> int:
        return sum(len(ax.terms) for ax in self.axes)

    @property
    def n_states(self) -> int:
        """Distinct filter states: lags and rates of one channel with one a share one."""
        return len({t.state for ax in self.axes for t in ax.terms if t.kind in FILTER_KINDS})

    def all_terms(self) -> list[QTerm]:
        return [t for ax in self.axes for t in ax.terms]
