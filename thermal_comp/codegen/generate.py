"""The codegen API: model dict -> header text + fixed_point block; files written atomically."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

from thermal_comp.codegen.bound import FINAL_ROUNDING_NM, AxisBound, model_bounds
from thermal_comp.codegen.crc import model_crc32
from thermal_comp.codegen.errors import BoundError, CodegenError
from thermal_comp.codegen.quantise import QModel, checked_spec, quantise
from thermal_comp.codegen.render import render
from thermal_comp.contract import __version__ as CODEGEN_VERSION
from thermal_comp.contract.box import HEADER_FORMAT
from thermal_comp.contract.fixed_point import ACC_LIMIT, DEFAULT_MAX_ERROR_UM
from thermal_comp.contract.model_file import (
    ModelFormatError,
    ModelSpec,
    read_model,
    write_text_atomic,
)


@dataclass(frozen=True)
class GeneratedHeader:
    """The rendered header and the numbers behind it (``fixed_point`` goes into model.json)."""

    text: str
    fixed_point: dict
    model: QModel
    bounds: tuple[AxisBound, ...]
    crc32: int
    spec: ModelSpec  # the checked model it was generated from, typed


def _check_bounds(bounds: list[AxisBound], model: QModel, max_error_um: float) -> None:
    limit = Fraction(max_error_um)
    for b, ax in zip(bounds, model.axes, strict=True):
        if b.bound_exact_um <= limit:
            continue
        # Name the largest single part of the bound: a term's share, or the final rounding.
        worst = max(b.terms, key=lambda e: e.total_nm, default=None)
        if worst is None or worst.total_nm <= FINAL_ROUNDING_NM:
            detail = (f"; largest part: the final rounding to whole nanometres "
                      f"({float(FINAL_ROUNDING_NM) / 1000:g} um), which no model avoids")
        else:
            t = worst.term
            why = (f"state quantisation {float(worst.state_nm) / 1000:.3g} um: its alpha "
                   f"{t.param / 2**30:.3g} is too small for the 16-bit filter state fraction"
                   if worst.state_nm >= worst.coef_nm else
                   f"coefficient quantisation {float(worst.coef_nm) / 1000:.3g} um")
            detail = (f"; largest part: term {t.position} {t.label}, coef {t.coef_um!r} "
                      f"{t.coef_unit}, {why}")
        raise BoundError(
            f"axis '{ax.name}': worst-case fixed-point error {b.bound_um:.6g} um exceeds "
            f"--max-error-um {max_error_um:g}{detail}")


def _fixed_point_block(model: QModel, bounds: list[AxisBound], crc32: int,
                       max_error_um: float, zero_at_powerup: bool = False) -> dict:
    return {
        "header_format": HEADER_FORMAT,
        "zero_at_powerup": zero_at_powerup,
        "codegen_version": CODEGEN_VERSION,
        "model_hash": model.model_hash,
        "crc32": f"0x{crc32:08X}",
        "max_error_um": max_error_um,
        "temp_lsb_c": 1 / 128,
        "sample_period_ms": model.period_ms,
        "time_max_samples": model.time_max_samples,
        "acc_limit": ACC_LIMIT,
        "channels": [{"channel": c.index, "sensor": c.sensor, "min_code": c.min_code,
                      "max_code": c.max_code, "window_lo_code": c.window_lo_code,
                      "window_hi_code": c.window_hi_code, "max_step_code": c.max_step_code,
                      "max_step_source": c.max_step_source,
                      "max_still_samples": c.max_still_samples} for c in model.channels],
        "aux": [{"input": a.index, "name": a.name, "min": a.min, "max": a.max}
                for a in model.aux],
        "axes": {
            ax.name: {
                "shift": ax.shift,
                "intercept_q": ax.intercept_q,
                "terms": [{"kind": t.kind, "source": t.source, "input": t.input,
                           "param": t.param, "coef_q": t.coef_q, "max_abs_x": t.xmax}
                          for t in ax.terms],
                "acc_max": ax.acc_max,
                "out_max_nm": ax.out_max_nm,
                "max_step_nm": ax.max_step_nm,
                "max_step_source": ax.max_step_source,
                **b.to_json(),
            }
            for ax, b in zip(model.axes, bounds, strict=True)
        },
    }


def generate(model: Mapping | ModelSpec, max_error_um: float = DEFAULT_MAX_ERROR_UM,
             zero_at_powerup: bool | None = None) -> GeneratedHeader:
    """Quantise, prove and render ``model`` (a model.json dict, or its typed view); raises
    CodegenError.

    ``zero_at_powerup``: the header's TCM_ZERO_AT_POWERUP (the box behaves as if ZERO was
    received before its first sample, docs/protocol.md); by default it follows the model's
    reference: a model of the change since the start (``start``) zeroes at power-up."""
    if not max_error_um > 0:
        raise CodegenError(f"--max-error-um must be positive, got {max_error_um!r}")
    spec = checked_spec(model)
    if zero_at_powerup is None:
        zero_at_powerup = spec.reference.kind == "start"
    q = quantise(spec)
    bounds = model_bounds(q)
    _check_bounds(bounds, q, max_error_um)
    crc = model_crc32(q)
    text = render(q, bounds, crc, CODEGEN_VERSION, zero_at_powerup)
    return GeneratedHeader(text, _fixed_point_block(q, bounds, crc, max_error_um,
                                                    zero_at_powerup), q,
                           tuple(bounds), crc, spec)


def load_model(path: str | Path) -> dict:
    """A model file read and checked by ``contract.model_file.read_model`` (structure and
    stored hash), its refusals raised as CodegenError."""
    try:
        return read_model(path)
    except ModelFormatError as exc:
        raise CodegenError(str(exc)) from None


def export_to_c(model, max_error_um: float = DEFAULT_MAX_ERROR_UM, **options) -> str:
    """The firmware's model header (C text) for a model, the way m2cgen's ``export_to_c`` works.

    ``model`` is a model.json mapping, a path to one, any object with a ``to_model_json()``
    method (``host.train.estimator.ThermalModel``, fitted), or a scikit-learn Pipeline ending in
    one (the steps before it are handed to ``to_model_json(before=...)``, which refuses any
    that transforms the inputs: the box would not apply it). Raises :class:`BoundError` when the
    proven fixed-point error exceeds ``max_error_um`` and :class:`CodegenError` for a model the
    box cannot run. ``generate`` returns the same text with the fixed_point block and the
    quantised model beside it; ``options`` are generate's (e.g. ``zero_at_powerup``).
    """
    if hasattr(model, "to_model_json"):
        model = model.to_model_json()
    elif hasattr(model, "steps"):  # a scikit-learn Pipeline: its last step with those before it
        steps = [step for _, step in model.steps]
        if not hasattr(steps[-1], "to_model_json"):
            raise CodegenError(f"the Pipeline ends in {type(steps[-1]).__name__}, not a thermal "
                               "model (host.train.estimator.ThermalModel): nothing to export")
        model = steps[-1].to_model_json(before=steps[:-1])
    elif isinstance(model, str | Path):
        model = load_model(Path(model))
    return generate(model, max_error_um, **options).text


def fixed_point_path(header_path: str | Path) -> Path:
    """Where ``write_header`` puts the fixed_point block: beside the header (model.h.json)."""
    header_path = Path(header_path)
    return header_path.with_name(header_path.name + ".json")


def write_header(model_json_path: str | Path, header_path: str | Path,
                 max_error_um: float = DEFAULT_MAX_ERROR_UM,
                 zero_at_powerup: bool | None = None) -> GeneratedHeader:
    """Generate ``header_path`` from a model.json, and its fixed_point block beside it.

    The model file is only read, never rewritten (it is the user's); nothing is written unless
    generation succeeds; each file is replaced atomically.
    """
    model_json_path, header_path = Path(model_json_path), Path(header_path)
    model = load_model(model_json_path)
    try:
        gen = generate(model, max_error_um, zero_at_powerup)
    except CodegenError as exc:
        raise type(exc)(f"{model_json_path}: {exc}") from None
    write_text_atomic(header_path, gen.text)
    write_text_atomic(fixed_point_path(header_path), json.dumps(gen.fixed_point, indent=2) + "\n")
    return gen
