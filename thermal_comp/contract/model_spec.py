"""A checked model's function, typed: what codegen, the twin and the host read after the check.

The dict stays the file's full content (metrics, traces); the typed view holds only what the
box computes, so a reader cannot mistake a report field for part of the model.
"""

from __future__ import annotations

from dataclasses import dataclass

from thermal_comp.contract.terms import Term


@dataclass(frozen=True)
class ChannelSpec:
    channel: int
    sensor: str
    tc_type: str
    min_c: float
    max_c: float
    trained_min_c: float | None
    trained_max_c: float | None


@dataclass(frozen=True)
class AuxSpec:
    input: int
    name: str
    min: float
    max: float
    trained_min: float | None
    trained_max: float | None


@dataclass(frozen=True)
class AxisSpec:
    name: str
    unit: str
    intercept: float
    terms: tuple[Term, ...]
    coefs: tuple[float, ...]


@dataclass(frozen=True)
class ModelSpec:
    """A checked model's function, typed (the dict stays the file's full content)."""

    sample_period_s: float
    channels: tuple[ChannelSpec, ...]  # in channel order
    aux: tuple[AuxSpec, ...]  # in input order
    time_max_s: float | None
    axes: tuple[AxisSpec, ...]
    model_hash: str

    @property
    def sensors(self) -> list[str]:
        return [c.sensor for c in self.channels]

    @property
    def aux_names(self) -> list[str]:
        return [a.name for a in self.aux]

    def channel(self, sensor: str) -> ChannelSpec:
        return next(c for c in self.channels if c.sensor == sensor)
