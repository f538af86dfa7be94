"""A checked model's function, typed: what codegen, the box's twins and the host read after the
check ("typed results inside, JSON at the edge", issue 44).

Typed here: everything the box computes or acts on (the function's hash covers it): the sample
period, the channels with their ranges and input limits, the aux inputs, time_max_s, the
reference, and per axis its unit, intercept, terms and coefficients, output step limit and
in-service estimator block; plus the tilts (how a µrad axis is measured). Each field is built
where its rule is checked (``model_file``, ``model_axis``, ``model_checker``), so there is one
home for each fact.

Left in the dict ("JSON at the edge"): what explains or reports the model but changes nothing
the box does (``metrics``, ``selection``, ``effects``, ``fit``, ``baseline``, ``training``, a
service block's ``why``...) and codegen's ``fixed_point`` block (its own output). The reports
(host.analysis.report*, metrology, host.train.summary, the demo) read those from the dict, and
the writers (host train, the service refit, the campaigns' deliberate edits) build the dict.
Readers get the typed view from ``model_file.read_model_spec`` (a file) or ``spec_of`` (a dict
handed over at the edge).
"""

from __future__ import annotations

from dataclasses import dataclass

from thermal_comp.contract.service import SERVICE_FIELDS
from thermal_comp.contract.terms import Term, term_sensors
from thermal_comp.contract.tilt import Tilt


@dataclass(frozen=True)
class ChannelSpec:
    channel: int
    sensor: str
    tc_type: str
    min_c: float
    max_c: float
    trained_min_c: float | None
    trained_max_c: float | None
    max_step_c: float | None  # None: a model written before the step limits were kept
    max_still_samples: int | None  # None: a model written before the stuck check


@dataclass(frozen=True)
class AuxSpec:
    input: int
    name: str
    min: float
    max: float
    trained_min: float | None
    trained_max: float | None


@dataclass(frozen=True)
class ServiceSpec:
    """An axis's in-service estimator parameters (docs/service.md): the fields of
    ``contract.service.SERVICE_FIELDS`` by the same names, the optional ones filled in."""

    q_um2_per_h: float
    probe_noise_um: float
    gate_sigma: float
    gate_floor_um: float
    p_max_um2: float
    residual_noise_um: float
    reopen_after: float

    def values(self) -> dict[str, float]:
        """The parameters by SERVICE_FIELDS name, in its order (the estimators' keywords)."""
        return {k: getattr(self, k) for k in SERVICE_FIELDS}


@dataclass(frozen=True)
class ReferenceSpec:
    """What zero means (docs/model-json.md): ``start`` (the change since the mean of the first
    ``samples``), or ``none`` (also a model written before references were kept)."""

    kind: str = "none"
    samples: int = 1


@dataclass(frozen=True)
class AxisSpec:
    name: str
    unit: str
    intercept: float
    terms: tuple[Term, ...]
    coefs: tuple[float, ...]
    max_step_um: float | None  # None: a model written before the step limits were kept
    service: ServiceSpec | None  # None: a model trained before issue 42 (the fallbacks)

    @property
    def sensors(self) -> list[str]:
        """The channels the axis's terms read, each once, in term order."""
        return term_sensors(self.terms)


@dataclass(frozen=True)
class ModelSpec:
    """A checked model's function, typed (module docstring: what stays in the dict)."""

    sample_period_s: float
    channels: tuple[ChannelSpec, ...]  # in channel order
    aux: tuple[AuxSpec, ...]  # in input order
    time_max_s: float | None
    axes: tuple[AxisSpec, ...]  # in the file's order (the box's)
    model_hash: str
    reference: ReferenceSpec
    tilts: tuple[Tilt, ...]  # the µrad axes' gap probes (none for a model without them)

    @property
    def sensors(self) -> list[str]:
        return [c.sensor for c in self.channels]

    @property
    def aux_names(self) -> list[str]:
        return [a.name for a in self.aux]

    @property
    def axis_names(self) -> list[str]:
        return [a.name for a in self.axes]

    def channel(self, sensor: str) -> ChannelSpec:
        return next(c for c in self.channels if c.sensor == sensor)

    def axis(self, name: str) -> AxisSpec:
        """The axis ``name``; KeyError naming it when the model has no such axis."""
        for ax in self.axes:
            if ax.name == name:
                return ax
        raise KeyError(name)
