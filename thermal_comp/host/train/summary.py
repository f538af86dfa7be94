"""The ``host train --json`` document: what each axis uses and how well it did."""

from __future__ import annotations

from thermal_comp.contract.terms import TEMPERATURE_KINDS
from thermal_comp.host.effects.scoring import MIN_GAIN
from thermal_comp.host.train.nested import FAMILIES


def axis_sensors(axis: dict) -> list[str]:
    """Temperature sources of an axis's terms, in term order, each once."""
    out: list[str] = []
    for t in axis["terms"]:
        if t["kind"] in TEMPERATURE_KINDS and t["source"] not in out:
            out.append(t["source"])
    return out


def free_channels(axis: dict) -> list[str]:
    """Sensors the axis's ridge reads besides the ones selected for it (its free channels)."""
    return list((axis.get("fit") or {}).get("free_channels_read") or [])


def summary(model: dict, model_path: str) -> dict:
    """The ``host train --json`` document (a fixed shape scripts rely on, plus a few extras)."""
    axes = {}
    for name, axis in model["axes"].items():
        m = axis["metrics"]
        axes[name] = {
            "sensors": axis_sensors(axis),
            "train_rmse_um": m["train_rmse_um"],
            "validation_rmse_um": m["validation_rmse_um"],
            "raw_rms_um": m["raw_rms_um"],
            "r2": m.get("r2"),
            "max_abs_um": m.get("max_abs_um"),
            "condition_number": m.get("condition_number"),
            "validation": m.get("validation"),
            # the RMS promised for an unseen day, from the folds of the pipeline refitted
            # without each fold (nested.promise_from_folds), and its coverage: "RMS on an
            # unseen day <= X um on 80 % of days" (nested.promise_statement)
            "promised_rmse_um": m.get("promised_rmse_um"),
            "promised_fold_rmse_um": m.get("promised_fold_rmse_um"),
            "promised_coverage": m.get("promised_coverage"),
            "promise": m.get("promise"),
            "fit": (axis.get("fit") or {}).get("family"),
            # > 0 for a --bending axis: its ridge's response to an even warming, penalised
            "even_warming_penalty": (axis.get("fit") or {}).get("even_warming_penalty", 0.0),
            # sensors the ridge reads on the box's free channels (L1 ranking), not selected
            "free_channels_read": free_channels(axis),
            # the loop: before/after the effects, what was added and what is still unexplained
            "baseline_validation_rmse_um": axis.get("baseline_validation_rmse_um"),
            # the search's own figure after its effects (least squares on its folds); the box's
            # model (validation_rmse_um above) may be another family, fitted on other folds
            "effects_validation_rmse_um": axis.get("validation_rmse_um"),
            "effects": [{k: e.get(k) for k in ("kind", "feature", "evidence", "rmse_before_um",
                                               "rmse_after_um", "dropped_for_channels",
                                               "dropped_by_nested_validation",
                                               "dropped_by_box_ridge",
                                               "in_ridge_lags")}
                        for e in axis.get("effects", [])],
            "unexplained": axis.get("unexplained"),
            # why the box's model runs without the accepted effects (None: it runs them)
            "effects_rejected": axis.get("effects_rejected"),
            # what the channel budget took away after the effects (None: nothing)
            "channel_budget_after_effects": axis.get("channel_budget_after_effects"),
            # the loop's before/after on the model the box runs (None: no effects or no
            # nested validation)
            "box_nested_rmse_um": box_effects_evidence(axis),
        }
    return {"model": model_path, "axes": axes}


def box_effects_evidence(axis: dict) -> dict | None:
    """The box's family refitted on the nested folds with its effects and without them
    (host.train.nested: the whole pipeline, effects search included, trained without each
    fold and scored on it): the closed loop's before/after on the model the box runs, where
    the effects' own before/after is least squares on the selected terms. None without
    effects or nested validation.

    A noisy judge of one training file's effects (docs/training.md measures how often
    it agrees with the unseen runs), shown so a user can weigh them; it decides nothing here."""
    fit = axis.get("fit") or {}
    rms = (fit.get("nested") or {}).get("rmse_um") or {}
    if not axis.get("effects"):
        return None
    shrunk = str(fit.get("family", "")).startswith("ridge")

    def family(with_effects: bool) -> str:  # the box's kind of fit (nested.FAMILIES)
        return next(f for f, kind in FAMILIES.items() if kind == (with_effects, shrunk))

    with_key, without_key = family(True), family(False)
    if with_key not in rms or without_key not in rms:
        return None
    return {"with_effects": rms[with_key], "without_effects": rms[without_key],
            "families": [with_key, without_key]}


def dropped_reason(effect: dict) -> str | None:
    """Why an accepted effect is not in the box's model (None when it is)."""
    if effect.get("dropped_for_channels"):
        return "no box channel left for its sensor"
    if effect.get("dropped_by_nested_validation"):
        return "nested validation predicted the unseen folds better without it"
    if effect.get("dropped_by_box_ridge"):
        return (f"the box's ridge is not {100 * MIN_GAIN:.0f} % lower on its own folds with "
                "the effects")
    return None


def ridge_lags_note(effect: dict) -> str | None:
    """How the box's ridge models a lag or rate effect (None: it runs the effect's own terms):
    with its own lags of the effect's sensor (host.train.ridge_family.ridge_start)."""
    lags = effect.get("in_ridge_lags")
    if lags is None:
        return None
    if not lags:
        return "the box's ridge reads its sensor; no lag of it fits the box's filter states"
    return "the box's ridge models it with " + ", ".join(lags)


def box_model_note(axis: dict) -> str | None:
    """How the box's model differs from the last accepted effect's (None: it is that model)."""
    notes = []
    after = axis.get("channel_budget_after_effects")
    if after:
        notes.append("the channel budget dropped " + ", ".join(after.get("dropped_terms") or []))
    if axis.get("effects_rejected"):
        notes.append("without the effects ("
                     + ("the box's ridge" if any(e.get("dropped_by_box_ridge")
                                                 for e in axis.get("effects", []))
                        else "nested validation") + ")")
    if (axis.get("fit") or {}).get("family", "ols").startswith("ridge"):
        extra = free_channels(axis)
        notes.append("a ridge over the terms plus lags and speed"
                     + (f", reading {', '.join(extra)} on free channels" if extra else "")
                     + (", its lags standing for the lag effects"
                        if any(ridge_lags_note(e) for e in axis.get("effects", [])) else ""))
    return "; ".join(notes) or None
