"""Closing the loop: candidates, scoring, re-selection, residual structure, box limits, search.

docs/effects.md explains every choice; ``search_effects`` is the entry point.
"""

from __future__ import annotations

from thermal_comp.host.effects.box_limits import fixed_point_refusal, state_quantisation_um
from thermal_comp.host.effects.candidates import (
    TAU_GRID_S,
    Candidate,
    EffectsError,
    find_ambient,
    generate_candidates,
    tau_grid,
)
from thermal_comp.host.effects.report import AddedEffect, EffectsReport
from thermal_comp.host.effects.residual import lag1_autocorrelation, noise_floor, residual_structure
from thermal_comp.host.effects.scoring import (
    FeatureCache,
    GramScorer,
    Rule,
    Scored,
    candidate_row,
    partial_correlation,
    preferred,
    score_candidates,
)
from thermal_comp.host.effects.search import EffectsResult, search_effects
from thermal_comp.host.effects.sensor_reference import sensor_reference

__all__ = [
    "AddedEffect",
    "Candidate",
    "EffectsError",
    "EffectsReport",
    "EffectsResult",
    "FeatureCache",
    "GramScorer",
    "Rule",
    "Scored",
    "TAU_GRID_S",
    "candidate_row",
    "find_ambient",
    "fixed_point_refusal",
    "generate_candidates",
    "lag1_autocorrelation",
    "noise_floor",
    "partial_correlation",
    "preferred",
    "residual_structure",
    "score_candidates",
    "search_effects",
    "sensor_reference",
    "state_quantisation_um",
    "tau_grid",
]
