"""Stage 2 of codegen: a quantised model -> the text of model.h (jinja2, no arithmetic).

This module only *formats*: every number was decided by ``codegen.quantise`` and
``codegen.bound``. The template sees ready-made strings (C literals, macro names, comments)
and ``StrictUndefined`` turns a missing one into an error instead of empty text.
"""

from __future__ import annotations

import math
from fractions import Fraction

import jinja2

from thermal_comp.codegen.bound import AxisBound
from thermal_comp.codegen.quantise import X_UNIT_TEXT, QAux, QAxis, QChannel, QModel, QTerm
from thermal_comp.contract.box import HEADER_FORMAT
from thermal_comp.contract.fixed_point import INT32_MIN
from thermal_comp.contract.terms import FILTER_KINDS

GUARD = "TCM_GENERATED_MODEL_H"

_ENV = jinja2.Environment(
    loader=jinja2.PackageLoader(__package__, "templates"),
    undefined=jinja2.StrictUndefined,
    autoescape=False,  # C, not HTML
    keep_trailing_newline=True,
    trim_blocks=True,
    lstrip_blocks=True,
)


def c_int32(v: int) -> str:
    # INT32_C(-2147483648) would be the negation of a too-wide literal.
    return "(-INT32_C(2147483647) - 1)" if v == INT32_MIN else f"INT32_C({v})"


def c_int64(v: int) -> str:
    return f"INT64_C({v})"


def _num(x: float) -> str:
    """Shortest text that reads back as the same double (repr), for comments."""
    return repr(float(x))


def _ceil_pm(um: Fraction) -> int:
    return math.ceil(um * 10**6)


def _term_view(t: QTerm, ax_prefix: str, model: QModel) -> dict:
    prefix = f"{ax_prefix}_TERM{t.position}"
    if t.kind in ("temp", "lag", "rate", "square"):
        ch = model.channels[t.input]
        lo, hi = f"TCM_CH{ch.index}_MIN_CODE", f"TCM_CH{ch.index}_MAX_CODE"
        what = f"channel {ch.index} ({ch.sensor})"
    elif t.kind in ("speed", "speed2"):
        a = model.aux[t.input]
        lo, hi = f"TCM_AUX{a.index}_MIN", f"TCM_AUX{a.index}_MAX"
        what = f"aux {a.index} ({a.name})"
    else:
        lo = hi = ""
        what = "(samples since power-up)"
    param_macro = f"{prefix}_PARAM"
    if t.kind == "time":
        param_lit = "TCM_TIME_MAX_SAMPLES"
        xmax_expr = f"TCM_XMAX_TIME({param_macro})"
    elif t.kind == "square":
        param_lit = c_int32(t.param)
        xmax_expr = f"TCM_XMAX_SQUARE({lo}, {hi}, {param_macro})"
    else:
        param_lit = c_int32(t.param)
        xmax_expr = f"TCM_XMAX_{t.kind.upper()}({lo}, {hi})"
    extra = ""
    if t.kind in FILTER_KINDS:
        tau = t.params.get("tau_s")
        extra = (f", tau {_num(tau)} s" if tau is not None else "") + \
            f", a = alpha*2^30 = {t.param}"
    elif t.kind == "square":
        extra = f", reference {_num(t.param / 128)} degC = code {t.param}"
    elif t.kind == "time":
        extra = f", saturating at {t.param} samples"
    return {
        "position": t.position,
        "description": f"{t.kind} {what}{extra}",
        "coef_um": _num(t.coef_um),
        "coef_unit": t.coef_unit,
        "x_unit": X_UNIT_TEXT[t.kind],
        "xmax": t.xmax,
        "coef_macro": f"{prefix}_COEF_Q",
        "coef_lit": c_int64(t.coef_q),
        "param_macro": param_macro,
        "param_lit": param_lit,
        "xmax_macro": f"{prefix}_XMAX",
        "xmax_expr": xmax_expr,
        "filter": t.kind in FILTER_KINDS,
        "range_lo": lo,
        "range_hi": hi,
        "kind_upper": t.kind.upper(),
        "input": t.input,
        "state": t.state or 0,
    }


def view(model: QModel, bounds: list[AxisBound], crc32: int, codegen_version: str,
         zero_at_powerup: bool = False) -> dict:
    """Everything the template prints, as strings and flags."""
    axes = [_axis_view(ax, b, model) for ax, b in zip(model.axes, bounds, strict=True)]
    return {
        "codegen_version": codegen_version,
        "header_format": HEADER_FORMAT,
        "guard": GUARD,
        "schema": model.schema,
        "model_hash": model.model_hash,
        "period_ms": model.period_ms,
        "crc32": f"0x{crc32:08X}",
        "zero_at_powerup": 1 if zero_at_powerup else 0,
        "n_channels": len(model.channels),
        "n_aux": len(model.aux),
        "n_axes": len(model.axes),
        "n_terms": model.n_terms,
        "n_states": model.n_states,
        "channels": [_channel_view(ch) for ch in model.channels],
        "aux": [_aux_view(a) for a in model.aux],
        "time_max": {"seconds": _num(model.time_max_s), "lit": c_int32(model.time_max_samples)}
        if any(t.kind == "time" for t in model.all_terms()) else None,
        "axes": axes,
        "term_count_sum": " + ".join(f"{a['prefix']}_N_TERMS" for a in axes),
        "tables": {
            "channels": "tcm_channels" if model.channels else "NULL",
            "aux": "tcm_aux" if model.aux else "NULL",
            "terms": "tcm_terms" if model.n_terms else "NULL",
        },
    }


def _axis_view(ax: QAxis, b: AxisBound, model: QModel) -> dict:
    prefix = f"TCM_AXIS{ax.index}"
    return {
        "index": ax.index,
        "name": ax.name,
        "prefix": prefix,
        "shift": ax.shift,
        "n_terms": len(ax.terms),
        "intercept_um": _num(ax.intercept_um),
        "intercept_q_lit": c_int64(ax.intercept_q),
        "terms": [{**tv, "coef_unit": tv["coef_unit"].replace("um/", f"{ax.unit}/")}
                  for tv in (_term_view(t, prefix, model) for t in ax.terms)],
        "unit": ax.unit,  # um, or urad for a tilt axis (contract/tilt.py)
        "nano": "nanoradians" if ax.unit == "urad" else "nanometres",
        "pico": "picoradians" if ax.unit == "urad" else "picometres",
        "bound": {k: _num(v) for k, v in b.to_json().items()},
        "bound_pm": _ceil_pm(b.bound_exact_um),
        "input_pm": _ceil_pm(sum((e.input_um for e in b.terms), Fraction(0))),
        "max_step_lit": c_int32(ax.max_step_nm),
        "max_step_um": _num(ax.max_step_nm / 1000),
        "max_step_default": ax.max_step_source == "default",
        "service": _service_view(ax),
    }


def _service_view(ax: QAxis) -> dict:
    """The axis's estimator parameters as header literals (docs/service.md, "Fixed point");
    all zero and ``on`` 0 without a service block (the box answers MEAS with OFF)."""
    sv = ax.service
    p = f"TCM_AXIS{ax.index}_SVC_"
    fields = [("q_q8", "Q_Q8", c_int64(sv.q_q8 if sv else 0)),
              ("r_q8", "R_Q8", c_int64(sv.r_q8 if sv else 0)),
              ("floor2_nm2", "FLOOR2_NM2", c_int64(sv.floor2_nm2 if sv else 0)),
              ("pmax_q8", "PMAX_Q8", c_int64(sv.pmax_q8 if sv else 0)),
              ("g2_q8", "G2_Q8", f"{sv.g2_q8 if sv else 0}u"),
              ("on", "ON", f"{int(sv is not None)}u"),
              ("p0_pmax", "P0_PMAX", f"{int(bool(sv and sv.p0_q8))}u"),
              ("reopen_after", "REOPEN_AFTER", f"{sv.reopen_after if sv else 0}u")]
    return {"on": int(sv is not None),
            "fields": [{"name": n, "macro": p + m, "lit": lit} for n, m, lit in fields]}


def _channel_view(ch: QChannel) -> dict:
    return {
        "index": ch.index, "sensor": ch.sensor, "tc_type": ch.tc_type,
        "min_c": _num(ch.min_c), "max_c": _num(ch.max_c),
        "min_macro": f"TCM_CH{ch.index}_MIN_CODE", "max_macro": f"TCM_CH{ch.index}_MAX_CODE",
        "min_lit": c_int32(ch.min_code), "max_lit": c_int32(ch.max_code),
        "win_lo_macro": f"TCM_CH{ch.index}_WINDOW_LO",
        "win_hi_macro": f"TCM_CH{ch.index}_WINDOW_HI",
        "win_lo_lit": c_int32(ch.window_lo_code), "win_hi_lit": c_int32(ch.window_hi_code),
        "win_lo_c": _num(ch.window_lo_code / 128), "win_hi_c": _num(ch.window_hi_code / 128),
        "has_window": (ch.window_lo_code, ch.window_hi_code) != (ch.min_code, ch.max_code),
        "step_macro": f"TCM_CH{ch.index}_MAX_STEP",
        "step_lit": c_int32(ch.max_step_code),
        "step_c": _num(ch.max_step_code / 128),
        "step_default": ch.max_step_source == "default",
        "still_macro": f"TCM_CH{ch.index}_MAX_STILL",
        "still_lit": f"{ch.max_still_samples}u",
        "still": ch.max_still_samples,
    }


def _aux_view(a: QAux) -> dict:
    return {
        "index": a.index, "name": a.name,
        "min_value": _num(a.min_value), "max_value": _num(a.max_value),
        "min_macro": f"TCM_AUX{a.index}_MIN", "max_macro": f"TCM_AUX{a.index}_MAX",
        "min_lit": c_int32(a.min), "max_lit": c_int32(a.max),
    }


def render(model: QModel, bounds: list[AxisBound], crc32: int, codegen_version: str,
           zero_at_powerup: bool = False) -> str:
    return _ENV.get_template("model.h.j2").render(
        view(model, bounds, crc32, codegen_version, zero_at_powerup))
