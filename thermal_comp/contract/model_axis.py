"""The rules of one axis of model.json: its unit, its terms and what they can reach.

Each term must be wired to a channel or aux input the model declares and carry the parameters
its kind needs; the sum of what the terms can reach over the declared input ranges must fit the
box's int32 nanometre output, so a 1e30 coefficient is refused here, not printed as 1e31 um.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping

from thermal_comp.contract.box import RUNTIME_MAX_TERMS_PER_AXIS
from thermal_comp.contract.fixed_point import INT32_MAX
from thermal_comp.contract.model_checker import Checker, is_number
from thermal_comp.contract.model_spec import AuxSpec, AxisSpec, ChannelSpec, ServiceSpec
from thermal_comp.contract.service import SERVICE_FIELDS, SERVICE_OPTIONAL, service_value_problem
from thermal_comp.contract.terms import AUX_KINDS, FILTER_KINDS, KINDS, TEMPERATURE_KINDS, Term
from thermal_comp.contract.tilt import AXIS_UNITS, unit_of

OUTPUT_LIMIT_UM = INT32_MAX / 1000  # the box's output is int32 nanometres


def term_label(kind: object, source: object, t: Mapping) -> str:
    tau, ref = t.get("tau_s"), t.get("ref_c")
    if kind in FILTER_KINDS and is_number(tau) and math.isfinite(tau):
        return f"{kind}({source}, tau={tau:g}s)"
    if kind == "square" and is_number(ref) and math.isfinite(ref):
        return f"square({source}-{ref:g}C)"
    if kind == "time":
        return "time"
    return f"{kind}({source})"


def check_axis(c: Checker, name: object, ax: object, channels: list[ChannelSpec],
               aux: list[AuxSpec], time_max_s: float | None, output_range: bool) -> AxisSpec:
    """Axis ``name`` of the model: unit, intercept, step limit, service block, terms."""
    name = c.name(name, f"axes.{name}")
    if not isinstance(ax, Mapping):
        c.fail(f"axis '{name}': expected an object")
    unit = ax.get("unit", "um")
    if unit not in AXIS_UNITS:
        c.fail(f"axis '{name}': unit {unit!r} is not supported (one of {', '.join(AXIS_UNITS)})")
    if unit != unit_of(name):
        c.fail(f"axis '{name}': unit {unit!r}, but the name declares {unit_of(name)!r} (a tilt "
               "axis's name ends in '_urad', every other axis is in um)")
    intercept = c.number(ax.get("intercept"), f"axis '{name}': intercept")
    max_step = c.step_limit(ax, f"axis '{name}'", name, "max_step_um", unit)
    service = _check_service(c, name, ax.get("service"))
    raw = ax.get("terms")
    if not isinstance(raw, list):
        c.fail(f"axis '{name}': 'terms' must be a list")
    if len(raw) > RUNTIME_MAX_TERMS_PER_AXIS:
        c.fail(f"axis '{name}': {len(raw)} terms exceed {RUNTIME_MAX_TERMS_PER_AXIS} "
               "(contract.box.RUNTIME_MAX_TERMS_PER_AXIS)")
    by_sensor = {ch.sensor: ch for ch in channels}
    by_aux = {a.name: a for a in aux}
    terms, coefs, reach = [], [], []
    for j, t in enumerate(raw):
        term, coef, part = _check_term(c, name, j, t, by_sensor, by_aux, time_max_s)
        terms.append(term)
        coefs.append(coef)
        reach.append(part)
    if output_range:
        _check_output_range(c, name, intercept, reach)
    return AxisSpec(name, unit, intercept, tuple(terms), tuple(coefs), max_step, service)


def _check_term(c: Checker, name: str, j: int, t: object, by_sensor: Mapping[str, ChannelSpec],
                by_aux: Mapping[str, AuxSpec], time_max_s: float | None
                ) -> tuple[Term, float, tuple[float, str, float]]:
    """Term ``j`` of axis ``name``: its kind, source and parameters; returns the term, its
    coefficient and (its largest contribution over the input ranges, its label, coef)."""
    where = f"axis '{name}' term {j}"
    if not isinstance(t, Mapping):
        c.fail(f"{where}: expected an object, got {t!r}")
    kind, source = t.get("kind"), t.get("source")
    if kind not in KINDS:
        c.fail(f"{where}: unknown term kind {kind!r} (known: {', '.join(KINDS)})")
    where = f"{where} {term_label(kind, source, t)}"
    coef = c.number(t.get("coef"), f"{where}: coef")
    params = {}
    for k, v in t.items():
        if k not in ("kind", "source", "coef"):
            params[k] = c.number(v, f"{where}: {k}")
    if kind in TEMPERATURE_KINDS or kind in AUX_KINDS:
        if not isinstance(source, str):  # {} or [] was a TypeError (unhashable) here
            c.fail(f"{where}: source must be the name of a "
                   f"{'channel' if kind in TEMPERATURE_KINDS else 'aux input'} "
                   f"(a string), got {json.dumps(source)}")
    if kind in TEMPERATURE_KINDS:
        if source not in by_sensor:
            c.fail(f"{where}: source {source!r} is not in 'channels' "
                   f"({', '.join(by_sensor) or 'none'})")
        lo, hi = by_sensor[source].min_c, by_sensor[source].max_c
    elif kind in AUX_KINDS:
        if source not in by_aux:
            c.fail(f"{where}: source {source!r} is not in 'aux' "
                   f"({', '.join(by_aux) or 'none'})")
        lo, hi = by_aux[source].min, by_aux[source].max
    else:  # time
        if source is not None:
            c.fail(f"{where}: a time term has no source (got {source!r})")
        if time_max_s is None:
            c.fail(f"{where}: the model needs time_max_s for a time term")
        lo, hi = 0.0, time_max_s
    if kind in FILTER_KINDS:
        for k in ("tau_s", "alpha"):
            if k not in params:
                c.fail(f"{where}: a {kind} term needs '{k}'")
        if not params["tau_s"] > 0:
            c.fail(f"{where}: tau_s {params['tau_s']!r} must be positive")
        if not 0 < params["alpha"] <= 1:
            c.fail(f"{where}: alpha {params['alpha']!r} must be in (0, 1] "
                   "(make it with contract.terms.make_lag/make_rate)")
    elif kind == "square" and "ref_c" not in params:
        c.fail(f"{where}: a square term needs 'ref_c'")
    term = Term(kind, source, params)
    return term, coef, (abs(coef) * _feature_reach(kind, lo, hi, params), where, coef)


def _check_output_range(c: Checker, name: str, intercept: float,
                        reach: list[tuple[float, str, float]]) -> None:
    """The axis's output over the declared input ranges fits the box's int32 nanometres."""
    total = abs(intercept) + sum(r for r, _, _ in reach)
    if not total <= OUTPUT_LIMIT_UM * (1 + 1e-9):
        part = ""
        if reach:
            r, where, coef = max(reach, key=lambda x: x[0])
            part = f"; largest part: {where.removeprefix(f'axis {name!r} ')}, coef " \
                   f"{coef!r}, up to {r:.6g} um"
        c.fail(f"axis '{name}': the output can reach {total:.6g} um over the declared "
               f"input ranges, beyond the box's int32 nanometre limit "
               f"{OUTPUT_LIMIT_UM:.6g} um{part}")


def _check_service(c: Checker, axis: str, block: object) -> ServiceSpec | None:
    """``axes.<axis>.service`` (docs/service.md): the in-service estimator's parameters, each
    within the range its fixed-point arithmetic is proven for (contract.service); the optional
    ones a block leaves out get SERVICE_OPTIONAL's values."""
    if block is None:
        return None  # a model trained before issue 42: the estimator uses its fallbacks
    where = f"axis '{axis}': service"
    if not isinstance(block, Mapping):
        c.fail(f"{where}: expected an object of {', '.join(SERVICE_FIELDS)}, got {block!r}")
    values = {}
    for key in SERVICE_FIELDS:
        if key not in block and key in SERVICE_OPTIONAL:
            values[key] = SERVICE_OPTIONAL[key]
            continue
        if key not in block:
            c.fail(f"{where}.{key}: missing (one of {', '.join(SERVICE_FIELDS)})")
        v = c.number(block[key], f"{where}.{key}")
        if problem := service_value_problem(key, v):
            c.fail(f"{where}.{key}: {problem}")
        values[key] = v
    why = block.get("why", "")
    if not isinstance(why, str):
        c.fail(f"{where}.why: expected text, got {why!r}")
    return ServiceSpec(**values)


def _feature_reach(kind: str, lo: float, hi: float, params: Mapping[str, float]) -> float:
    """max |feature| over the declared input range [lo, hi] (docs/codegen.md, proof 2)."""
    m = max(abs(lo), abs(hi))
    if kind in ("temp", "lag", "speed", "time"):
        return m
    if kind == "rate":
        return hi - lo
    if kind == "speed2":
        return m * m
    if kind == "square":
        ref = params["ref_c"]
        return max(abs(lo - ref), abs(hi - ref)) ** 2
    raise AssertionError(kind)
