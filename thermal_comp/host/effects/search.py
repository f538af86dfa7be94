"""Close the loop: find what the validation residual lacks and add it, validated.

A static model delta = C0 + sum Ci*Ti (paper 000) cannot represent thermal lag (pseudo-
hysteresis), ambient drift, speed-dependent growth, a slow trend or a nonlinear rise. Each of
those has a small family of extra terms the box computes causally (contract/terms.py, all in the
fixed-point contract). Starting from the baseline selection, ``search_effects``:

1. takes the *out-of-fold* residual of the current model (leave-one-run-out, or contiguous
   time blocks of one run: host/fitting/validation.py), never the training residual alone;
2. scores every candidate family: its partial correlation with that residual (evidence only)
   and the out-of-fold RMSE of the current terms plus the family, per fold and overall; the
   families of a measured input (shop air, spindle speed) are also scored with the sensors
   re-selected given that input, because a static selection picks stand-ins for an input
   (``reselected_candidates``), and must then also beat the re-selected sensors alone;
3. adds the best candidate only if it is material and stable (the rule, ``passes``): at least
   ``MIN_GAIN`` (10 %) lower validation RMSE *and* a lower held-out RMSE in every fold. The
   thresholds are fixed a priori for unseen runs, not tuned to a dataset;
4. refuses a candidate the box could not run within the codegen error bound (the lag state
   quantisation bound grows as 1/alpha, so long time constants with large coefficients can
   break the 0.01 um default) and takes the next passing one instead;
5. refits and repeats, at most ``MAX_EFFECTS`` (3) times.

When no candidate passes and the residual is still structured (lag-1 autocorrelation well
above white noise *and* RMSE well above the measurement noise floor), the report says so
(``unexplained``) instead of forcing a term. docs/effects.md explains every choice.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from thermal_comp.contract.terms import Term, term_sensors
from thermal_comp.host.effects.box_limits import MAX_ERROR_UM, fixed_point_refusal
from thermal_comp.host.effects.candidates import (
    TAU_GRID_S,
    Candidate,
    EffectsError,
    find_ambient,
    generate_candidates,
    start_reference,
    tau_grid,
)
from thermal_comp.host.effects.report import AddedEffect, EffectsReport
from thermal_comp.host.effects.reselection import Reselection, reselected_candidates
from thermal_comp.host.effects.residual import (
    NOISE_MULTIPLE,
    noise_floor,
    residual_structure,
    rounded,
)
from thermal_comp.host.effects.scoring import (
    FeatureCache,
    Rule,
    Scored,
    candidate_row,
    every_nth,
    preferred,
    score_candidates,
    search_stride,
)
from thermal_comp.host.fitting import (
    DEFAULT_BLOCKS,
    NO_REFERENCE,
    Reference,
    fit_linear,
    fold_groups,
)
from thermal_comp.host.io import Run
from thermal_comp.host.selection import DEFAULT_MAX_SENSORS

EFFECT_KINDS = ("lag", "rate", "ambient", "speed", "drift", "nonlinear")
MAX_EFFECTS = 3
TOP_RECORDED = 5  # candidates kept per step in the report


@dataclass
class EffectsResult:
    """Final terms and fit, and the search's report (model.json's axis keeps its JSON)."""

    terms: list[Term]
    coefs: np.ndarray
    intercept: float
    report: EffectsReport


def _unexplained_message(structure: dict, n_added: int, best: dict | None,
                         max_reached: bool, rule: Rule) -> str:
    head = (f"after {n_added} effect{'s' if n_added != 1 else ''} " if n_added else "")
    msg = (f"{head}the validation residual is still structured (lag-1 autocorrelation "
           f"{structure['lag1_autocorr']:.2f}, white noise would stay below "
           f"{structure['white_noise_limit']:.2f}; RMSE {structure['residual_rmse_um']:.3g} um "
           f"vs a noise floor of {structure['noise_floor_um']:.3g} um)")
    if max_reached:
        return msg + f"; the limit of {MAX_EFFECTS} effects was reached"
    if best is None:
        return msg + ", and no candidate effect applies"
    return (msg + "; no candidate effect explains it: the best, "
            f"{best['kind']} {best['feature']}, lowers the validation RMSE by "
            f"{best['improvement_pct']:.1f} % with {best['folds_improved']} folds improved "
            f"(needs >= {rule.min_gain:.0%} and every fold that exercises it better)")


@dataclass
class _Space:
    """What one axis's search works on: the (thinned) target and its folds, the candidates'
    features, the inputs a family may use and the channel budget it must keep."""

    sensors: list[str]
    aux_names: list[str]
    ambient: str | None
    period_s: float
    taus: list[float]
    scheme: str
    floor: float  # the gauge's noise (full rate)
    y: np.ndarray
    groups: np.ndarray
    run_ids: np.ndarray
    cache: FeatureCache
    refs: dict
    how: Reselection
    allowed_new: int
    baseline_sources: set[str]
    channels_in_use: set[str]

    def fits_budget(self, c: Candidate, terms: list[Term]) -> bool:
        """The channels the box wires grow by at most ``allowed_new`` (a re-selection that
        gives up a sensor nobody else reads frees its channel)."""
        wired = set(term_sensors(c.apply(terms))) | self.channels_in_use
        return len(wired) - len(self.baseline_sources) <= self.allowed_new

    def candidates(self, terms: list[Term], kinds: set[str]) -> list[Candidate]:
        """Every family that applies to ``terms``, with the input families re-selected, that
        keeps the channel budget."""
        cands = [c for c in generate_candidates(terms, self.sensors, self.aux_names,
                                                self.ambient, self.period_s, self.taus,
                                                self.refs) if c.kind in kinds]
        cands += reselected_candidates(cands, self.cache, self.y, self.groups, self.run_ids,
                                       terms, self.sensors, self.ambient, self.period_s,
                                       self.scheme, self.how, self.allowed_new,
                                       self.baseline_sources)
        return [c for c in cands if self.fits_budget(c, terms)]


@dataclass
class _Outcome:
    """Where the loop stopped: the terms, what it added, and its last scores."""

    terms: list[Term]
    added: list[AddedEffect]
    steps: list[dict]
    n_tested: int
    last_best: dict | None
    max_reached: bool
    baseline_score: Scored
    ref: Scored
    residual: np.ndarray


def _space(runs: list[Run], target: str, baseline: Sequence[Term], period_s: float, *,
           ambient: str | None, aux: Sequence[str] | None, n_blocks: int,
           taus: Iterable[float], selection: Mapping | None, max_sensors: int,
           allowed_new: int, channels_in_use: Iterable[str], reference: Reference) -> _Space:
    sensors = list(runs[0].sensor_names)
    aux_names = _checked_aux(runs[0], aux)
    ambient = find_ambient(sensors, ambient)
    shortest = min(r.time_s[-1] - r.time_s[0] for r in runs)
    stride = search_stride(runs)
    groups_full, scheme = fold_groups(runs, n_blocks)
    y_full = np.concatenate([reference.apply(r.target(target)) for r in runs])
    run_ids = np.concatenate([np.full(r.n_samples, i) for i, r in enumerate(runs)])
    in_use = set(channels_in_use)
    return _Space(
        sensors=sensors, aux_names=aux_names, ambient=ambient, period_s=period_s,
        taus=tau_grid(period_s, shortest, taus), scheme=scheme,
        floor=noise_floor(y_full, groups_full), y=every_nth(runs, stride, y_full),
        groups=every_nth(runs, stride, groups_full), run_ids=every_nth(runs, stride, run_ids),
        cache=FeatureCache(runs, period_s, stride, reference),
        refs={s: start_reference(runs, s) for s in sensors},
        how=Reselection.from_trace(selection, max_sensors), allowed_new=allowed_new,
        baseline_sources=set(term_sensors(baseline)) | in_use, channels_in_use=in_use)


def _loop(space: _Space, baseline: Sequence[Term], kinds: set[str], rule: Rule,
          max_effects: int, max_error_um: float) -> _Outcome:
    """Steps 1-5: score every candidate on the current residual, add the first the box can
    run that passes the rule, refit, repeat."""
    terms = list(baseline)
    added: list[AddedEffect] = []
    steps: list[dict] = []
    n_tested = 0
    last_best: dict | None = None
    baseline_score: Scored | None = None
    while True:
        ref, residual, scored = score_candidates(space.cache, space.y, space.groups, terms,
                                                 space.candidates(terms, kinds))
        if baseline_score is None:
            baseline_score = ref
        if len(added) >= max_effects:
            return _Outcome(terms, added, steps, n_tested, last_best, True, baseline_score,
                            ref, residual)
        if not residual_structure(residual, space.y, space.groups, space.floor)["above_noise"]:
            break  # the residual is at the gauge's noise: no effect to look for
        n_tested += len(scored)
        chosen = _first_the_box_runs(scored, ref, rule, terms, space.cache, space.y,
                                     max_error_um)
        top = [candidate_row(s, ref) for s in scored[:TOP_RECORDED]]
        refused = [candidate_row(s, ref) for s in scored[TOP_RECORDED:] if s.codegen]
        steps.append({"validation_rmse_um": rounded(ref.validation_rmse_um, 4),
                      "candidates": len(scored), "best": top + refused,
                      "added": None if chosen is None else chosen.candidate.feature})
        last_best = top[0] if top else None
        if chosen is None:
            break
        assert chosen.candidate is not None
        terms = chosen.candidate.apply(terms)
        fit = fit_linear(space.cache.matrix(terms), space.y)
        added.append(_added_entry(chosen, ref, terms, fit.coef, fit.intercept))
    return _Outcome(terms, added, steps, n_tested, last_best, False, baseline_score, ref,
                    residual)


def search_effects(runs: Sequence[Run], target: str, baseline: Sequence[Term], period_s: float,
                   *, ambient: str | None = None, aux: Sequence[str] | None = None,
                   max_effects: int = MAX_EFFECTS, n_blocks: int = DEFAULT_BLOCKS,
                   rule: Rule | None = None, max_error_um: float = MAX_ERROR_UM,
                   taus: Iterable[float] = TAU_GRID_S, kinds: Iterable[str] = EFFECT_KINDS,
                   selection: Mapping | None = None, max_sensors: int = DEFAULT_MAX_SENSORS,
                   max_new_sensors: int | None = None, channels_in_use: Iterable[str] = (),
                   reference: Reference = NO_REFERENCE) -> EffectsResult:
    """Add up to ``max_effects`` validated effects to the ``baseline`` terms of one axis.

    ``ambient`` is the ambient sensor (default: a sensor named like *amb*, if any); ``aux`` the
    aux columns speed terms may use (default: every aux column of the runs). ``selection``
    (the baseline's selection trace) and ``max_sensors`` say how an input's family re-selects
    the sensors; ``max_new_sensors`` (default ``max_effects``: host.train's channel budget
    counts on at most one new sensor per effect) caps the sensors outside the baseline's and
    ``channels_in_use`` (sensors another axis already wires, which cost no channel).
    """
    runs = list(runs)
    rule = rule or Rule()
    if not runs:
        raise EffectsError("no runs")
    kinds = _checked_kinds(kinds)
    space = _space(runs, target, baseline, period_s, ambient=ambient, aux=aux,
                   n_blocks=n_blocks, taus=taus, selection=selection, max_sensors=max_sensors,
                   allowed_new=max_effects if max_new_sensors is None else int(max_new_sensors),
                   channels_in_use=channels_in_use, reference=reference)
    base_fit = fit_linear(space.cache.matrix(list(baseline)), space.y)
    out = _loop(space, baseline, kinds, rule, max_effects, max_error_um)
    final = fit_linear(space.cache.matrix(out.terms), space.y)
    structure = residual_structure(out.residual, space.y, space.groups, space.floor)
    unexplained = None
    if structure["structured"]:
        unexplained = {k: structure[k] for k in ("lag1_autocorr", "white_noise_limit",
                                                  "residual_rmse_um", "noise_floor_um")}
        unexplained["message"] = _unexplained_message(structure, len(out.added),
                                                      out.last_best, out.max_reached, rule)
    report = EffectsReport(
        baseline_validation_rmse_um=rounded(out.baseline_score.validation_rmse_um, 6),
        validation_rmse_um=rounded(out.ref.validation_rmse_um, 6),
        effects=tuple(out.added),
        baseline_terms=tuple(baseline),
        baseline_coefs=tuple(float(c) for c in base_fit.coef),
        baseline_intercept=float(base_fit.intercept),
        unexplained=unexplained,
        search={
            "rule": _rule_text(rule, max_effects, max_error_um),
            "validation": space.scheme,
            "kinds": [k for k in EFFECT_KINDS if k in kinds],
            "ambient": space.ambient,
            "aux": space.aux_names,
            "tau_grid_s": space.taus,
            "candidates_tested": out.n_tested,
            "residual": structure,
            "steps": out.steps,
        },
    )
    return EffectsResult(out.terms, final.coef, float(final.intercept), report)


def _checked_kinds(kinds: Iterable[str]) -> set[str]:
    kinds = set(kinds)
    unknown = kinds - set(EFFECT_KINDS)
    if unknown:
        raise EffectsError(f"unknown effect kind(s) {sorted(unknown)} (known: "
                           f"{', '.join(EFFECT_KINDS)})")
    return kinds


def _checked_aux(run: Run, aux: Sequence[str] | None) -> list[str]:
    """The aux columns speed terms may use: ``aux``, or every aux column of the runs."""
    names = list(run.aux_names if aux is None else aux)
    for name in names:
        if name not in run.aux_names:
            raise EffectsError(f"aux column '{name}' is not in {run.path}")
    return names


def _first_the_box_runs(scored: Sequence[Scored], ref: Scored, rule: Rule, terms: list[Term],
                        cache: FeatureCache, y: np.ndarray, max_error_um: float
                        ) -> Scored | None:
    """The preferred passing candidate the box can run within its error bound (step 4); the
    refused ones keep their reason in ``codegen``."""
    for s in preferred([s for s in scored if s.passes(ref, rule)]):
        assert s.candidate is not None
        trial = s.candidate.apply(terms)
        fit = fit_linear(cache.matrix(trial), y)
        s.codegen = fixed_point_refusal(trial, fit.coef, max_error_um)
        if s.codegen is None:
            return s
    return None


def _added_entry(chosen: Scored, ref: Scored, terms: list[Term], coefs: np.ndarray,
                 intercept: float) -> AddedEffect:
    """The report's record of an added effect, with the model's terms after it."""
    cand = chosen.candidate
    assert cand is not None
    return AddedEffect(
        kind=cand.kind, feature=cand.feature, added=tuple(cand.add),
        removed=tuple(cand.remove or ()), reselected=bool(cand.family),
        evidence=chosen.evidence(ref), rmse_before_um=rounded(ref.validation_rmse_um, 4),
        rmse_after_um=rounded(chosen.validation_rmse_um, 4), intercept=float(intercept),
        terms=tuple(terms), coefs=tuple(float(c) for c in coefs))


def _rule_text(rule: Rule, max_effects: int, max_error_um: float) -> str:
    return (f"{rule.describe()}; searched only while the residual RMSE exceeds "
            f"{NOISE_MULTIPLE:g}x the gauge noise; at most {max_effects} effects; the "
            f"box's error bound must hold (<= {max_error_um:g} um)")
