"""The effects search's result, typed: what it added, and the record model.json keeps of it.

Training reads these fields (the terms before the effects, the effects and their flags); the
JSON (``to_json``) is written once, by host.train.record, with the keys and order model.json
has always had. The search's step-by-step trace (``effects_search``) and the residual's
verdict (``unexplained``) are records for people and stay JSON objects.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from thermal_comp.contract.terms import Term


def terms_json(terms: Sequence[Term], coefs: Sequence[float]) -> list[dict]:
    """Terms with their coefficients, as model.json writes them."""
    return [{**t.to_json(), "coef": float(c)} for t, c in zip(terms, coefs, strict=True)]


@dataclass(frozen=True)
class AddedEffect:
    """One effect the search added: the candidate's terms, its evidence and the axis after it."""

    kind: str
    feature: str
    added: tuple[Term, ...]
    removed: tuple[Term, ...]  # the sensors a re-selected family replaced
    reselected: bool
    evidence: Mapping[str, Any]
    rmse_before_um: float
    rmse_after_um: float
    intercept: float  # the axis's fit after this effect
    terms: tuple[Term, ...]
    coefs: tuple[float, ...]

    def to_json(self) -> dict:
        return {
            "kind": self.kind,
            "feature": self.feature,
            "name": self.feature,
            "added": [t.to_json() for t in self.added],
            **({"reselected": True} if self.reselected else {}),
            **({"removed": [t.to_json() for t in self.removed]} if self.removed else {}),
            "evidence": dict(self.evidence),
            "rmse_before_um": self.rmse_before_um,
            "rmse_after_um": self.rmse_after_um,
            "intercept": self.intercept,
            "terms": terms_json(self.terms, self.coefs),
        }


@dataclass(frozen=True)
class EffectsReport:
    """The search on one axis: validation before and after, the effects in the order added,
    the baseline's fit, and the records for people (``unexplained``, ``search``)."""

    baseline_validation_rmse_um: float
    validation_rmse_um: float
    effects: tuple[AddedEffect, ...]
    baseline_terms: tuple[Term, ...]
    baseline_coefs: tuple[float, ...]
    baseline_intercept: float
    unexplained: Mapping[str, Any] | None = None
    search: Mapping[str, Any] = field(default_factory=dict)  # model.json ``effects_search``

    def to_json(self) -> dict:
        return {
            "baseline_validation_rmse_um": self.baseline_validation_rmse_um,
            "validation_rmse_um": self.validation_rmse_um,
            "effects": [e.to_json() for e in self.effects],
            "unexplained": None if self.unexplained is None else dict(self.unexplained),
            "baseline": {"intercept": self.baseline_intercept,
                         "terms": terms_json(self.baseline_terms, self.baseline_coefs)},
            "effects_search": dict(self.search),
        }
