"""`host diagnose`: a trained model on a new run -- its error, what explains the rest, which
sensors look faulty. Nothing is refitted or written.

Per axis: the model's error on the run (the float model, as the box computes it up to the
fixed-point bound); then the same candidate effects as ``host train`` (host/effects/), scored
on the *residual* with contiguous time blocks of this run: the residual is fitted by an offset
plus the candidate's terms on the other blocks and predicts the held-out block. The reference
is the offset alone (a constant error is not an effect), the acceptance rule the training's.

Per sensor the model reads: compared with its cluster-mates (the c-means group of the
selection trace, the redundant neighbours). Training stored, in ``sensor_reference``, a line
``s = a + b*m`` per mate; on the new run the gap ``s - (a + b*m)`` is watched for
- drift: a steady trend of the gap over the run, larger than both ``DRIFT_MIN_C`` and
  ``DRIFT_SIGMAS`` times the gap's training scatter, and seen alike against every mate (same
  sign, within a factor 2 of the median). A sensor's own drift shifts all its gaps by the same
  amount; a change of the machine's thermal state between runs (another day's shop air) moves
  the gaps to different mates differently, and a faulty mate moves only its own gap, so
  neither accuses a healthy sensor;
- stuck: the same reading for a long stretch while the mates move;
- noisy: sample-to-sample noise many times its training noise (or its mates').
And which inputs leave their training range (host.train.ranges): a larger error there is the
model extrapolating, not an effect or a sensor fault.
Without a stored reference (a model trained with --no-effects) the lines are fitted on the
first third of the run itself, which can only see drift that starts later.
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import channel_ranges, spec_of
from thermal_comp.contract.tilt import available_axes, probe_columns, unit_of
from thermal_comp.host.analysis.evaluate import measured, model_reference, predict
from thermal_comp.host.effects import (
    TAU_GRID_S,
    Candidate,
    FeatureCache,
    Rule,
    find_ambient,
    generate_candidates,
    noise_floor,
    preferred,
    residual_structure,
    score_candidates,
    tau_grid,
)
from thermal_comp.host.effects import candidate_row as _candidate_row
from thermal_comp.host.fitting import DEFAULT_BLOCKS, axis_terms, fit_linear, fold_groups, rmse
from thermal_comp.host.io import CsvFormat, Run, load_run, missing_sensors, read_header
from thermal_comp.host.train import describe, outside_training

DRIFT_MIN_C = 0.5  # a drift smaller than this over the run is not worth a technician's visit
DRIFT_SIGMAS = 5.0  # ... and it must stand out of the pair's training scatter this much
DRIFT_AGREEMENT = 0.5  # ... and every mate must see it: same sign, within a factor 2
STUCK_MIN_FRACTION = 0.2  # identical readings over at least 20 % of the run ...
STUCK_MIN_SAMPLES = 10
STUCK_MATES_MOVE_C = 0.5  # ... while the mates moved at least this much
NOISY_FACTOR = 5.0  # noise this many times the reference ...
NOISY_MIN_C = 0.05  # ... and above this (MAX31856 steps are 0.0078 degC)
TOP_CANDIDATES = 5


class DiagnoseError(InputError):
    """The run cannot be diagnosed with this model (missing sensor or axis columns)."""


# ------------------------------------------------------------------ loading


def _header(path: str | Path, fmt: CsvFormat | None = None) -> list[str]:
    return read_header(path, fmt)


def load_for_diagnosis(model: Mapping, path: str | Path, fill_gaps: int = 0,
                       fmt: CsvFormat | None = None) -> Run:
    """Load a run with every sensor of the training glob, the model's axes and aux inputs."""
    header = _header(path, fmt)
    spec = spec_of(model)
    tilts = list(spec.tilts)
    training = model.get("training", {})  # how it was trained: a report field, in the dict
    pattern = training.get("sensors", "T*")
    targets = available_axes(header, spec.axis_names, tilts)
    aux = spec.aux_names
    missing_aux = [a for a in aux if a not in header]
    if missing_aux:
        raise DiagnoseError(f"{path}, line 1: missing aux column(s) {', '.join(missing_aux)} "
                            "the model reads")
    aux = aux + [a for a in training.get("aux", []) if a in header and a not in aux]
    reserved = {"time_s", *probe_columns(spec.axis_names, tilts), *aux}
    if isinstance(pattern, str):
        sensors = [h for h in header if fnmatch.fnmatchcase(h, pattern) and h not in reserved]
    else:
        sensors = [s for s in pattern if s in header]
    missing = [s for s in spec.sensors if s not in header]
    if missing:
        raise DiagnoseError(f"{path}, line 1: " + missing_sensors(
            missing, [h for h in header if h not in reserved], "the model reads them"))
    for s in spec.sensors:
        if s not in sensors:
            sensors.append(s)
    return load_run(path, targets, sensors, aux, fill_gaps=fill_gaps, min_samples=6, fmt=fmt,
                    temperature_ranges=channel_ranges(spec), tilts=tilts)


# ------------------------------------------------------------------ the model's error


def diagnose_axis(model: Mapping, axis: str, run: Run, *, ambient: str | None = None,
                  n_blocks: int = DEFAULT_BLOCKS, rule: Rule | None = None,
                  reference: str | None = None) -> dict:
    """The model's error on the run and which candidate effect explains what remains.

    Measured and predicted drift are referenced as ``host evaluate`` does (the model's
    reference unless ``reference`` is given), and so are the candidates' features."""
    rule = rule or Rule()
    spec = spec_of(model)
    period = spec.sample_period_s
    terms, _, _ = axis_terms(spec, axis)
    ref_kind = model_reference(spec, reference)
    y = measured(spec, run, axis, reference)
    pred = predict(spec, run, reference)[axis]
    e = y - pred
    # its validation error: a report field (metrics), in the dict
    trained = (model["axes"][axis].get("metrics") or {}).get("validation_rmse_um")
    out: dict = {
        "rmse_um": rmse(e),
        "max_abs_um": float(np.max(np.abs(e))),
        "mean_um": float(np.mean(e)),
        "raw_rms_um": rmse(y - y[0]),
        "model_validation_rmse_um": trained,
        "ratio_to_validation": (rmse(e) / trained if trained else None),
    }
    groups, scheme = fold_groups([run], n_blocks)
    cache = FeatureCache([run], period, reference=ref_kind)
    taus = tau_grid(period, float(run.time_s[-1] - run.time_s[0]), TAU_GRID_S)
    refs = {s: float(run.column(s)[0]) for s in run.sensor_names}
    amb = find_ambient(run.sensor_names, ambient)
    cands = [Candidate(c.kind, c.add) for c in
             generate_candidates(terms, run.sensor_names, run.aux_names, amb, period, taus, refs)]
    ref, residual, scored = score_candidates(cache, e, groups, [], cands)
    structure = residual_structure(residual, y, groups)
    out["offset_only_rmse_um"] = ref.validation_rmse_um
    out["validation"] = (f"{scheme}: the residual is fitted by an offset plus the candidate's "
                         "terms on the other blocks; the model itself is not refitted")
    passing = preferred([s for s in scored if s.passes(ref, rule)]) \
        if structure["above_noise"] else []
    out["explained_by"] = [{
        "kind": s.candidate.kind, "feature": s.candidate.feature,
        "evidence": s.evidence(ref),
        "rmse_before_um": ref.validation_rmse_um, "rmse_after_um": s.validation_rmse_um,
    } for s in passing[:3] if s.candidate is not None]
    out["candidates"] = [_candidate_row(s, ref) for s in scored[:TOP_CANDIDATES]]
    out["residual"] = structure
    out["unexplained"] = None
    if structure["structured"] and not passing:
        best = out["candidates"][0] if out["candidates"] else None
        msg = (f"the model's residual on this run is structured (lag-1 autocorrelation "
               f"{structure['lag1_autocorr']:.2f}, RMSE {structure['residual_rmse_um']:.3g} um "
               f"vs a noise floor of {structure['noise_floor_um']:.3g} um) and no candidate "
               "effect explains it")
        if best:
            msg += (f" (best: {best['feature']}, {best['improvement_pct']:.1f} % with "
                    f"{best['folds_improved']} blocks improved)")
        out["unexplained"] = {k: structure[k] for k in ("lag1_autocorr", "residual_rmse_um",
                                                         "noise_floor_um")}
        out["unexplained"]["message"] = msg
    return out


# ------------------------------------------------------------------ sensor checks


def _references(model: Mapping) -> dict:
    """Per sensor its training reference (from any axis that stored one)."""
    out: dict = {}
    for spec in model["axes"].values():
        for s, ref in (spec.get("sensor_reference") or {}).items():
            out.setdefault(s, ref)
    return out


def _mates_from_trace(model: Mapping, sensor: str) -> list[str]:
    for spec in model["axes"].values():
        for group in (spec.get("selection") or {}).get("groups", []):
            if sensor in group:
                return [m for m in group if m != sensor]
    return []


def _own_reference(run: Run, sensor: str, mates: Sequence[str]) -> dict:
    """Fallback reference: mate lines fitted on the first third of the run itself."""
    n = max(3, run.n_samples // 3)
    s = run.column(sensor)[:n]
    pairs = {}
    for m in mates:
        x = run.column(m)[:n]
        fit = fit_linear(x[:, None], s)
        pairs[m] = {"intercept": fit.intercept, "slope": float(fit.coef[0]),
                    "rmse_c": rmse(s - fit.predict(x[:, None]))}
    return {"mates": list(mates), "pairs": pairs, "noise_c": None, "source": "first third of run"}


def _trend(t: np.ndarray, gap: np.ndarray) -> float:
    """Change of the gap over the run along its least-squares line in time."""
    A = np.column_stack([np.ones_like(t), t - t[0]])
    coef, *_ = np.linalg.lstsq(A, gap, rcond=None)
    return float(coef[1] * (t[-1] - t[0]))


def _longest_constant(x: np.ndarray) -> tuple[int, int]:
    """Start and length of the longest run of identical consecutive readings."""
    best_start, best_len, start = 0, 1, 0
    for i in range(1, x.size + 1):
        if i == x.size or x[i] != x[start]:
            if i - start > best_len:
                best_start, best_len = start, i - start
            start = i
    return best_start, best_len


def check_sensor(run: Run, sensor: str, ref: Mapping | None, fallback_mates: Sequence[str]
                 ) -> dict:
    """Drift, stuck and noise checks of one sensor against its mates (see module docstring)."""
    if ref is None or not [m for m in ref.get("mates", []) if m in run.sensor_names]:
        mates = [m for m in fallback_mates if m in run.sensor_names and m != sensor]
        ref = _own_reference(run, sensor, mates) if mates else {"mates": [], "pairs": {}}
    mates = [m for m in ref["mates"] if m in run.sensor_names and m in ref["pairs"]]
    evidence: dict = {"mates": mates, "reference": ref.get("source", "training")}
    faults: list[dict] = []
    if mates:
        _check_drift(run, sensor, ref, mates, evidence, faults)
    _check_stuck(run, sensor, mates, evidence, faults)
    _check_noise(run, sensor, ref, mates, evidence, faults)
    return {"status": faults[0]["fault"] if faults else "ok", "faults": faults,
            "evidence": evidence}


def _check_drift(run: Run, sensor: str, ref: Mapping, mates: list[str], evidence: dict,
                 faults: list[dict]) -> None:
    """Drifting: the gap to every mate's line from the reference moves the same way over the
    run, by more than DRIFT_MIN_C and DRIFT_SIGMAS times the mates' training scatter."""
    t = run.time_s
    x = run.column(sensor)
    drifts, scatter = [], []
    for m in mates:
        p = ref["pairs"][m]
        gap = x - (p["intercept"] + p["slope"] * run.column(m))
        drifts.append(_trend(t, gap))
        scatter.append(max(float(p["rmse_c"]), 1e-3))
    drift = float(np.median(drifts))
    sigma = float(np.max(scatter))  # the least redundant mate sets the bar
    d = np.array(drifts)
    consistent = bool(np.all(np.sign(d) == np.sign(drift))
                      and np.all(np.abs(d) >= DRIFT_AGREEMENT * abs(drift))
                      and np.all(np.abs(d) <= abs(drift) / DRIFT_AGREEMENT))
    evidence.update({"drift_c": drift, "drift_per_mate_c": dict(zip(mates, drifts,
                                                                    strict=True)),
                     "drift_consistent": consistent,
                     "training_scatter_c": sigma, "drift_sigmas": abs(drift) / sigma})
    if (consistent and abs(drift) >= DRIFT_MIN_C and abs(drift) >= DRIFT_SIGMAS * sigma):
        hours = (t[-1] - t[0]) / 3600.0
        faults.append({"fault": "drifting", "message": (
            f"{sensor} drifts {drift:+.2f} degC from its mates "
            f"({', '.join(mates)}) over {hours:.1f} h ({abs(drift) / sigma:.0f}x their "
            "training scatter)")})


def _check_stuck(run: Run, sensor: str, mates: list[str], evidence: dict,
                 faults: list[dict]) -> None:
    """Stuck: the longest run of one reading, long enough, while the mates moved (or, with
    no mates, a sensor that never changed)."""
    t = run.time_s
    x = run.column(sensor)
    start, length = _longest_constant(x)
    evidence["longest_constant_samples"] = int(length)
    if length >= max(STUCK_MIN_SAMPLES, STUCK_MIN_FRACTION * x.size):
        seg = slice(start, start + length)
        moved = max((float(np.ptp(run.column(m)[seg])) for m in mates), default=math.nan)
        own = float(np.ptp(x))
        evidence.update({"stuck_at_c": float(x[start]), "stuck_s": float(t[seg][-1] - t[start]),
                         "mates_moved_c": moved})
        if (mates and moved >= STUCK_MATES_MOVE_C) or (not mates and own == 0.0):
            faults.append({"fault": "stuck", "message": (
                f"{sensor} reads {x[start]:.3f} degC unchanged for "
                f"{(t[seg][-1] - t[start]) / 60:.0f} min while its mates moved {moved:.2f} degC")})


def _check_noise(run: Run, sensor: str, ref: Mapping, mates: list[str], evidence: dict,
                 faults: list[dict]) -> None:
    """Noisy: sample-to-sample noise NOISY_FACTOR times the reference's (the training's, else
    the mates' median) and at least NOISY_MIN_C."""
    x = run.column(sensor)
    seg_ids = np.zeros(x.size, dtype=int)
    noise = noise_floor(x, seg_ids)
    mate_noise = [noise_floor(run.column(m), seg_ids) for m in mates]
    reference_noise = ref.get("noise_c")
    if reference_noise is None and mate_noise:
        reference_noise = float(np.median(mate_noise))
    evidence.update({"noise_c": noise, "reference_noise_c": reference_noise})
    if (reference_noise is not None and noise >= NOISY_MIN_C
            and noise >= NOISY_FACTOR * max(reference_noise, 1e-4)):
        faults.append({"fault": "noisy", "message": (
            f"{sensor} is noisy: {noise:.3f} degC sample to sample, "
            f"{noise / max(reference_noise, 1e-4):.0f}x its reference {reference_noise:.4f} degC")})


def check_sensors(model: Mapping, run: Run) -> dict[str, dict]:
    """Checks of every sensor the model reads."""
    refs = _references(model)
    return {s: check_sensor(run, s, refs.get(s), _mates_from_trace(model, s))
            for s in spec_of(model).sensors if s in run.sensor_names}


# ------------------------------------------------------------------ the whole report


def diagnose(model: Mapping, run: Run, *, ambient: str | None = None,
             n_blocks: int = DEFAULT_BLOCKS, reference: str | None = None) -> dict:
    """Everything ``host diagnose`` reports, as a JSON-ready dict."""
    if run.n_samples < 2 * n_blocks:
        raise DiagnoseError(f"{run.path}: {run.n_samples} samples is too few for {n_blocks} "
                            "time blocks")
    spec = spec_of(model)
    period = spec.sample_period_s
    if abs(run.period_s - period) > 0.01 * period:
        raise DiagnoseError(f"{run.path}: sample period {run.period_s:g} s differs from the "
                            f"model's {period:g} s (its lag terms assume that period)")
    axes = {a: diagnose_axis(model, a, run, ambient=ambient, n_blocks=n_blocks,
                             reference=reference)
            for a in spec.axis_names if a in run.target_names}
    sensors = check_sensors(model, run)
    faulty = [{"sensor": s, **f, "evidence": c["evidence"]}
              for s, c in sensors.items() for f in c["faults"]]
    missing = [a for a in spec.axis_names if a not in run.target_names]
    return {"run": run.path, "samples": run.n_samples,
            "reference": model_reference(spec, reference).kind, "axes": axes,
            "axes_without_measurement": missing, "sensors": sensors, "faulty": faulty,
            "outside_training_range": outside_training(model, run)}


def summary_lines(doc: Mapping, units: Mapping[str, str] | None = None) -> list[str]:
    """The readable report (``units``: per input, for the training-range lines)."""
    lines = [f"run: {doc['run']} ({doc['samples']} samples)"]
    for axis, a in doc["axes"].items():
        val = a.get("model_validation_rmse_um")
        u = unit_of(axis)
        lines.append(f"{axis}: error RMSE {a['rmse_um']:.3g} {u} (max {a['max_abs_um']:.3g}, "
                     f"mean {a['mean_um']:+.3g})" + (f"; {a['ratio_to_validation']:.1f}x the "
                                                     f"training validation RMSE {val:.3g} {u}"
                                                     if val else ""))
        for e in a["explained_by"][:1]:
            ev = e["evidence"]
            lines.append(f"  explained by {e['kind']}: {e['feature']} -- residual "
                         f"{e['rmse_before_um']:.3g} -> {e['rmse_after_um']:.3g} {u} "
                         f"({ev['improvement_pct']:.0f} %, {ev['folds_improved']} blocks, "
                         f"residual correlation {ev['residual_corr']:+.2f})")
        if a["unexplained"]:
            lines.append(f"  unexplained: {a['unexplained']['message']}")
        elif not a["explained_by"]:
            lines.append("  nothing systematic left (residual at the noise level or no "
                         "candidate passes)")
    for a in doc.get("axes_without_measurement", []):
        lines.append(f"{a}: not measured in this run (sensor checks only)")
    if doc["faulty"]:
        for f in doc["faulty"]:
            lines.append(f"sensor {f['sensor']}: {f['fault']} -- {f['message']}")
    else:
        lines.append(f"sensors: {len(doc['sensors'])} checked, none looks faulty")
    if "outside_training_range" in doc:
        lines += describe(doc["outside_training_range"], units)
    return lines
