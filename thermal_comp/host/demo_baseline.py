"""Why the box's model can lose to its baseline on an unseen run, in facts (the demo's
closing table explains every such row with them): the family it runs and what chose it, what
nested validation said of that family against the baseline before the run was seen, the
effects it does not run, the sensors only it reads and which of them the run took beyond their
training range, the report's warnings on the fit, and where the error stands against the
promise. Facts from model.json and the report, not a verdict: which of them caused the loss is
not measured here. Apart from the demo's steps because reading a model is another job than
running commands.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from thermal_comp.host.train import DEFAULT_FIT, dropped_reason

FAMILY_WORDS = {  # host.train.nested.FAMILIES, in words
    "ols": "least squares on the selected terms with the effects",
    "baseline": "least squares on the selected sensors' temperatures (the table's baseline)",
    "ridge": "a ridge over the selected terms, their lags, speed and the free channels, with "
             "the effects",
    "ridge-baseline": "a ridge over the selected sensors, their lags, speed and the free "
                      "channels, without the effects",
}


def _um_list(values: Sequence[float]) -> str:
    return ", ".join(f"{v:.2f}" for v in values)


def worse_than_baseline(row: Mapping) -> bool:
    """An unseen run on which the box's model leaves more error than the baseline it started
    from (least squares on the selected sensors' temperatures)."""
    base = row.get("baseline_rms_um")
    return (not row.get("in_training", True) and base is not None
            and row["residual_rms_um"]["our model"] > base)


def why_worse_than_baseline(axis: str, row: Mapping, model: Mapping | None,
                            summary: Mapping, run_name: str) -> list[str]:
    """The facts model.json and the report hold about why the box's model can lose to its
    baseline on an unseen run (see the module docstring), in that order."""
    spec = (model or {}).get("axes", {}).get(axis)
    if spec is None:
        return ["model.json for this axis was not at hand: no reason can be given"]
    fit = spec.get("fit") or {}
    family = str(fit.get("family") or "ols")
    facts = [family_fact(spec, fit, family)]
    facts += nested_facts(fit, family)
    facts += effects_facts(spec)
    facts += inputs_facts(spec, fit, summary, run_name)
    table = next((c for c in summary.get("coefficients") or []
                  if isinstance(c, Mapping) and c.get("axis") == axis), None)
    for w in (table or {}).get("warnings") or []:
        facts.append(f"the report warns '{w.get('name')}': {w.get('text')}")
    metrics = spec.get("metrics") or {}
    promised = metrics.get("promised_rmse_um")
    if promised is not None:
        ours = row["residual_rms_um"]["our model"]
        facts.append(("still within" if ours <= promised else "ABOVE")
                     + f" its promise ({metrics.get('promise') or f'{promised:.2f} µm'})")
    return facts


def family_fact(spec: Mapping, fit: Mapping, family: str) -> str:
    """The family the box runs, in words, with its terms and what chose it."""
    requested = fit.get("requested")
    what = FAMILY_WORDS.get(family, family)
    n_terms = len(spec.get("terms", []))
    if requested == "auto":
        chosen = "chosen by nested validation (--fit auto: the family with the lowest error)"
    elif requested is not None:
        chosen = (f"chosen by --fit {requested}"
                  + (" (host train's default)" if requested == DEFAULT_FIT else "")
                  + ", not by nested validation on this axis")
        if requested == "ridge" and not family.startswith("ridge"):
            chosen += "; no ridge kept the box's fixed-point bound, so least squares"
    else:
        chosen = "a model.json without a fit record (least squares)"
    return f"it runs {family}: {what} ({n_terms} terms), {chosen}"


def nested_facts(fit: Mapping, family: str) -> list[str]:
    """What nested validation said of the family against the baseline, fold by fold, before
    the run was seen (or that there was none)."""
    nested = fit.get("nested") or {}
    rms, folds = nested.get("rmse_um") or {}, nested.get("fold_rmse_um") or {}
    if family in rms and "baseline" in rms and family != "baseline":
        a, b = rms[family], rms["baseline"]
        fa, fb = folds.get(family) or [], folds.get("baseline") or []
        better = sum(x < y for x, y in zip(fb, fa, strict=False))
        detail = (f"{family} {a:.2f} µm RMS (folds {_um_list(fa)}), the baseline {b:.2f} µm "
                  f"(folds {_um_list(fb)}), the baseline better in {better} of {len(fa)} "
                  "folds")
        best = min(rms, key=lambda f: rms[f])
        if a > b:
            return ["nested validation (the pipeline refitted without each training "
                    "fold) had already ranked it behind the baseline: " + detail
                    + (f"; lowest: {best}, {FAMILY_WORDS.get(best, best)}, "
                       f"{rms[best]:.2f} µm" if best not in (family, "baseline")
                       else "")]
        return ["nested validation (the pipeline refitted without each training "
                "fold) had ranked it ahead of the baseline, so the training folds "
                "did not foresee this: " + detail]
    if not rms:
        return ["trained without nested validation: model.json holds no out-of-fold "
                "comparison with the baseline"]
    return []


def effects_facts(spec: Mapping) -> list[str]:
    """The effects the loop found that the box does not run (and why), and those it runs
    that the baseline has not."""
    facts = []
    dropped: dict[str, list[str]] = {}
    kept = []
    for e in spec.get("effects", []):
        why = dropped_reason(e)
        if why:
            dropped.setdefault(why, []).append(e.get("name", "?"))
        else:
            kept.append(e.get("name", "?"))
    for why, names in dropped.items():
        facts.append(f"the effects the loop found, {', '.join(names)}, are not run: {why}"
                     + (f" ({spec['effects_rejected']})" if spec.get("effects_rejected")
                        else ""))
    if kept:
        facts.append(f"it runs effects the baseline has not: {', '.join(kept)}")
    return facts


def inputs_facts(spec: Mapping, fit: Mapping, summary: Mapping, run_name: str) -> list[str]:
    """The sensors only the box's model reads (free channels), the inputs this run took
    beyond their training range, and what the fit record says of refilling and the
    baseline's candidacy."""
    facts = []
    base_sensors = {t["source"] for t in (spec.get("baseline") or {}).get("terms", [])
                    if "source" in t}
    free = [s for s in fit.get("free_channels_read") or [] if s not in base_sensors]
    if free:
        facts.append(f"it also reads {', '.join(free)} on free channels, which the baseline "
                     "does not")
    beyond = [r["input"] for r in (summary.get("outside_training") or {}).get(run_name) or []]
    if beyond:
        only_box = [b for b in beyond if b in free]
        facts.append(f"this run takes {', '.join(beyond)} beyond their training range"
                     + (f" ({', '.join(only_box)} read by the box's model only)" if only_box
                        else ""))
    if fit.get("refilled_without_dropped_effects"):
        facts.append("its free channels were filled again after its effects were dropped")
    if fit.get("baseline_not_candidate"):
        facts.append(f"the baseline was no candidate: {fit['baseline_not_candidate']}")
    return facts
