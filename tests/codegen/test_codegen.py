"""codegen: quantisation, bound, hash, CRC, golden header, refusals, files and the twin.

Expectations are worked out by hand (in the comments) or recomputed independently from the
rules in docs/fixed-point.md (Fractions, hashlib, struct + zlib), never read back from the
code under test.
"""

from __future__ import annotations

import copy
import decimal
import hashlib
import json
import math
import re
import struct
import zlib
from decimal import Decimal
from fractions import Fraction

import numpy as np
import pytest
from test_codegen_models import MODELS, base, channel, model, term

from thermal_comp import codegen
from thermal_comp.codegen.fixed import FixedModel, temp_to_code
from thermal_comp.contract.fixed_point import rdiv
from thermal_comp.contract.model_file import check_model
from thermal_comp.contract.terms import make_lag, make_temp
from thermal_comp.host.cli import main as host_main

# ---- the one-term model, by hand ------------------------------------------------------------
# T01 valid -40..200 degC -> codes -5120..25600 (x128). dz = 0.75 um + 1.5 um/degC * T.
# In nm per code: c0 = 750, c = 1500/128 = 375/32. Accumulator bound at shift F (F >= 5,
# everything exact): 750*2^F + 375/32 * 2^F * 25600 = 300750 * 2^F <= 2^62
# <=> F <= 62 - log2(300750) = 62 - 18.198 -> F = 43.
# intercept_q = 750 * 2^43 = 6597069766656000; coef_q = 375 * 2^38 = 103079215104000.
# Both exact, so the bound is the final rounding alone: 0.5 nm = 0.0005 um; input
# quantisation 1.5 um/degC * 1/256 degC = 0.005859375 um.
ONE_SHIFT = 43
ONE_INTERCEPT_Q = 6597069766656000
ONE_COEF_Q = 103079215104000


def test_one_term_model_quantised_by_hand():
    gen = codegen.generate(model("one_term"))
    ax = gen.fixed_point["axes"]["dz_um"]
    assert (ax["shift"], ax["intercept_q"], ax["terms"][0]["coef_q"]) == (
        ONE_SHIFT, ONE_INTERCEPT_Q, ONE_COEF_Q)
    assert 750 * 2**43 == ONE_INTERCEPT_Q and 375 * 2**38 == ONE_COEF_Q
    assert ax["coef_quantisation_um"] == 0.0 and ax["state_quantisation_um"] == 0.0
    assert ax["bound_um"] == pytest.approx(0.0005, abs=1e-18)
    assert ax["input_quantisation_um"] == 0.005859375


def test_rounding_half_away_from_zero_with_negative_accumulators():
    # out = 750 + 375/32 * code nm. code 16 -> 937.5 -> 938; code -80 -> -187.5 -> -188;
    # code -5120 -> 750 - 60000 = -59250 exactly; code 1 -> 761.71875 -> 762.
    fm = FixedModel.from_model(model("one_term"))
    for code, expected in [(16, 938), (-80, -188), (-5120, -59250), (1, 762), (-1, 738)]:
        fm.reset()
        assert fm.step([code], 1) == ([expected], 1)
    # rdiv itself: ties away from zero, both signs, and F = 0 is the identity.
    assert [rdiv(v, 1) for v in (5, -5, 3, -3, -4)] == [3, -3, 2, -2, -2]
    assert [rdiv(v, 2) for v in (2, -2, 1, -1, 7)] == [1, -1, 0, 0, 2]
    assert rdiv(-7, 0) == -7


# ---- independent re-derivation of every shift and coefficient --------------------------------

def _doc_units(m: dict) -> dict:
    """docs/fixed-point.md's unit of x_j in the coefficient's unit, per kind."""
    return {"temp": Fraction(1, 128), "lag": Fraction(1, 128 * 65536),
            "rate": Fraction(1, 128 * 65536), "speed": Fraction(1), "speed2": Fraction(1),
            "square": Fraction(1, 128 * 128), "time": Fraction(m["sample_period_s"])}


def _doc_xmax(m: dict, t: dict) -> int:
    """max |x_j| over the declared ranges, from the feature table of docs/fixed-point.md."""
    k = t["kind"]
    if k == "time":
        return math.floor(Fraction(m["time_max_s"]) / Fraction(m["sample_period_s"]))
    if k in ("speed", "speed2"):
        a = next(a for a in m["aux"] if a["name"] == t["source"])
        n = max(abs(math.ceil(a["min"])), abs(math.floor(a["max"])))
        return n if k == "speed" else n * n
    c = next(c for c in m["channels"] if c["sensor"] == t["source"])
    lo, hi = math.ceil(c["min_c"] * 128), math.floor(c["max_c"] * 128)
    if k == "temp":
        return max(abs(lo), abs(hi))
    if k == "lag":  # the state is a running mix of in-range codes, times 2^16
        return max(abs(lo), abs(hi)) * 65536
    if k == "rate":  # T*2^16 - s, both within [lo, hi]*2^16
        return (hi - lo) * 65536
    ref = round(t["ref_c"] * 128)
    return max(abs(lo - ref), abs(hi - ref)) ** 2


def _half_away(x: Fraction) -> int:
    q = math.floor(abs(x) + Fraction(1, 2))
    return q if x >= 0 else -q


@pytest.mark.parametrize("name", sorted(MODELS))
def test_shift_is_the_largest_that_cannot_overflow(name):
    m = model(name)
    fp = codegen.generate(m).fixed_point
    units = _doc_units(m)
    for axis, ax in m["axes"].items():
        got = fp["axes"][axis]
        xmax = [_doc_xmax(m, t) for t in ax["terms"]]
        assert xmax == [t["max_abs_x"] for t in got["terms"]]

        def acc(f, ax=ax, xmax=xmax):
            iq = _half_away(Fraction(ax["intercept"]) * 1000 * 2**f)
            cq = [_half_away(Fraction(t["coef"]) * 1000 * units[t["kind"]] * 2**f)
                  for t in ax["terms"]]
            return iq, cq, abs(iq) + sum(abs(q) * max(x, 1) for q, x in zip(cq, xmax, strict=True))

        f = got["shift"]
        iq, cq, total = acc(f)
        assert (iq, cq) == (got["intercept_q"], [t["coef_q"] for t in got["terms"]])
        assert total <= 2**62
        assert f == 62 or acc(f + 1)[2] > 2**62, f"{axis}: shift {f} is not maximal"


def test_max_abs_x_per_kind_by_hand():
    fp = codegen.generate(model("all_kinds")).fixed_point["axes"]
    # dx: temp T01 |x| <= 25600; lag T02 25600*65536; rate T03 (15360+2560)*65536;
    # square T01 ref 25.015625 degC = 3202: max(|-5120-3202|, |25600-3202|)^2 = 22398^2;
    # time: 3000 s / 1 s = 3000 samples.
    assert [t["max_abs_x"] for t in fp["dx_um"]["terms"]] == [
        25600, 25600 * 65536, 17920 * 65536, 22398**2, 3000]
    # dy: speed 12000, speed2 12000^2, lag T01 25600*65536.
    assert [t["max_abs_x"] for t in fp["dy_um"]["terms"]] == [12000, 12000**2, 25600 * 65536]


# ---- model hash ---------------------------------------------------------------------------

def test_model_hash_is_the_documented_canonical_sha256():
    m = model("all_kinds")
    core = {"sample_period_s": m["sample_period_s"], "channels": m["channels"],
            "aux": m["aux"], "time_max_s": m["time_max_s"],
            "axes": {k: {"unit": v["unit"], "intercept": v["intercept"], "terms": v["terms"],
                         **({"max_step_um": v["max_step_um"]} if "max_step_um" in v else {})}
                     for k, v in m["axes"].items()}}
    assert "max_step_um" in m["axes"]["dz_um"]  # hashed when present
    expected = hashlib.sha256(json.dumps(core, sort_keys=True, separators=(",", ":"))
                              .encode()).hexdigest()[:16]
    assert codegen.model_hash(m) == expected


def test_model_hash_ignores_traces_but_not_the_function():
    m = model("all_kinds")
    h = codegen.model_hash(m)
    traced = copy.deepcopy(m)
    traced["axes"]["dx_um"]["metrics"] = {"train_rmse_um": 0.8}
    traced["axes"]["dx_um"]["selection"] = {"method": "x"}
    traced["fixed_point"] = {"anything": 1}
    traced["training"] = {"runs": ["other.csv"]}
    assert codegen.model_hash(traced) == h
    changed = copy.deepcopy(m)
    changed["axes"]["dx_um"]["terms"][0]["coef"] += 1e-12
    assert codegen.model_hash(changed) != h


# ---- the golden header -----------------------------------------------------------------------

def _one_term_crc() -> int:
    data = struct.pack("<IIII", 1, 0, 1, 1000)  # channels, aux, axes, period ms
    data += struct.pack("<iiiiiBH", -5120, 25600, -5120, 25600, 128, 0, 0)  # T01: -40..200
    # degC, no training range (window = valid range), no max_step_c (default 1 degC = 128 codes
    # per 1 s sample), type K, no max_still_samples (no stuck check: 0)
    data += struct.pack("<BBqi", ONE_SHIFT, 1, ONE_INTERCEPT_Q, 1000)  # default 1 um/s x 1 s
    data += struct.pack("<BBIB4q", 0, 0, 0, 0, 0, 0, 0, 0)  # no service block: estimator off
    data += struct.pack("<BBBiq", 0, 0, 0, 0, ONE_COEF_Q)  # temp, channel 0, no state, no param
    return zlib.crc32(data)


GOLDEN = """\
/*
 * Generated by codegen v{version} -- DO NOT EDIT.
 * Regenerate with: host codegen <model.json> -o <model.h>
 *
 * Model {hash} (schema thermal-model/1), sample period 1000 ms.
 * Output: per axis, int32_t nanometres. Inputs: int32_t temperature codes, LSB 1/128 degC
 * (MAX31856 LTCB >> 5, sign-extended); a code outside its channel's range below is a fault.
 * Arithmetic: docs/fixed-point.md (runtime format 7); bounds: docs/codegen.md.
 * Include this file from exactly one firmware source file.
 */
#ifndef TCM_GENERATED_MODEL_H
#define TCM_GENERATED_MODEL_H

#include <stdint.h>

#include "model_eval.h"

#define TCM_HEADER_FORMAT 7
#if TCM_HEADER_FORMAT != TCM_RUNTIME_FORMAT
#error "model.h is header format 7 but model_eval.h is another runtime format: regenerate \
model.h with the codegen matching this firmware (host codegen)"
#endif

#define TCM_SCHEMA "thermal-model/1"
#define TCM_TOOL_VERSION "{version}"
#define TCM_MODEL_HASH "{hash}"
#define TCM_N_CHANNELS 1u
#define TCM_N_AUX 0u
#define TCM_N_AXES 1u
#define TCM_N_TERMS 1u
#define TCM_N_STATES 0u
#define TCM_SAMPLE_PERIOD_MS 1000u
#define TCM_MODEL_CRC32 UINT32_C({crc}) /* CRC-32 of the tables (docs/fixed-point.md) */
/* 1: the box behaves as if ZERO was received before the first sample (host codegen
 * --zero-at-powerup); 0: corrections are absolute until the CNC side sends ZERO. */
#define TCM_ZERO_AT_POWERUP 0

/* ---- Input contract ------------------------------------------------------------------- */
/* Temperature code LSB = 1/128 degC; valid range per channel (inclusive): */
/* channel 0: T01, type K, -40.0 .. 200.0 degC */
#define TCM_CH0_MIN_CODE INT32_C(-5120)
#define TCM_CH0_MAX_CODE INT32_C(25600)
/* no training range: the window is the valid range (EXTRAP never set) */
#define TCM_CH0_WINDOW_LO INT32_C(-5120)
#define TCM_CH0_WINDOW_HI INT32_C(25600)
/* largest plausible change 1.0 degC per sample: the conservative default (model.json has no \
max_step_c) */
#define TCM_CH0_MAX_STEP INT32_C(128)
/* no stuck check (model.json has no max_still_samples) */
#define TCM_CH0_MAX_STILL 0u

/* ---- Axis 0: dz_um ----
 * out_nm = rdiv(intercept_q + sum_j coef_q[j] * x_j, 2^43): each integer below is
 * nanometres (per unit of x_j) times 2^43.
 * intercept: 0.75 um
 * term 0: temp channel 0 (T01)
 *         coef 1.5 um/degC, x_j in 1/128 degC, |x_j| <= 25600
 * Worst-case |error| against the real-valued model fed the same quantised inputs, over the
 * whole declared input range, in um (rounded up; derivation in docs/codegen.md):
 *   coefficient quantisation  0.0
 *   filter state quantisation 0.0
 *   final rounding            0.0005
 *   bound (their sum)         0.0005
 *   input quantisation        0.005859375 (+-1/256 degC per temperature, not in the bound)
 */
#define TCM_AXIS0_SHIFT 43u
#define TCM_AXIS0_N_TERMS 1u
#define TCM_AXIS0_INTERCEPT_Q INT64_C(6597069766656000)
#define TCM_AXIS0_TERM0_COEF_Q INT64_C(103079215104000)
#define TCM_AXIS0_TERM0_PARAM INT32_C(0)
#define TCM_AXIS0_TERM0_XMAX TCM_XMAX_TEMP(TCM_CH0_MIN_CODE, TCM_CH0_MAX_CODE)
#define TCM_AXIS0_ACC_MAX \\
    (TCM_ABS64(TCM_AXIS0_INTERCEPT_Q) + \\
     TCM_ACC_TERM(TCM_AXIS0_TERM0_COEF_Q, TCM_AXIS0_TERM0_XMAX))
#define TCM_AXIS0_BOUND_PM 500u /* error bound, picometres (rounded up) */
#define TCM_AXIS0_INPUT_QUANT_PM 5860u /* input quantisation, picometres */
/* output step limit 1.0 um per sample: the default (model.json has no max_step_um) */
#define TCM_AXIS0_MAX_STEP_NM INT32_C(1000)
/* no in-service estimator (model.json has no service block for this axis): MEAS is refused (OFF) */
#define TCM_AXIS0_SVC_Q_Q8 INT64_C(0)
#define TCM_AXIS0_SVC_R_Q8 INT64_C(0)
#define TCM_AXIS0_SVC_FLOOR2_NM2 INT64_C(0)
#define TCM_AXIS0_SVC_PMAX_Q8 INT64_C(0)
#define TCM_AXIS0_SVC_G2_Q8 0u
#define TCM_AXIS0_SVC_ON 0u
#define TCM_AXIS0_SVC_P0_PMAX 0u
#define TCM_AXIS0_SVC_REOPEN_AFTER 0u
_Static_assert(TCM_AXIS0_MAX_STEP_NM >= 1, "axis 0 (dz_um): output step limit must be at least \
1 nm");
_Static_assert(TCM_AXIS0_SHIFT <= TCM_MAX_SHIFT, "axis 0 (dz_um): shift out of range");
_Static_assert(TCM_AXIS0_ACC_MAX <= TCM_ACC_LIMIT,
               "axis 0 (dz_um): the int64 accumulator could overflow");
_Static_assert(TCM_RDIV_CONST(TCM_AXIS0_ACC_MAX, TCM_AXIS0_SHIFT) <= INT32_MAX,
               "axis 0 (dz_um): the output could overflow int32_t");
_Static_assert(TCM_SVC_PARAMS_OK(TCM_AXIS0_SVC_ON, TCM_AXIS0_SVC_Q_Q8, TCM_AXIS0_SVC_R_Q8, \
TCM_AXIS0_SVC_G2_Q8, TCM_AXIS0_SVC_FLOOR2_NM2, TCM_AXIS0_SVC_PMAX_Q8, TCM_AXIS0_SVC_P0_PMAX, \
TCM_AXIS0_SVC_REOPEN_AFTER),
               "axis 0 (dz_um): estimator parameters outside the ranges the fixed-point \
arithmetic is proven for");

/* ---- Invariants of the tables --------------------------------------------------------- */
_Static_assert(TCM_N_CHANNELS <= TCM_MAX_CHANNELS, "too many channels for the runtime");
_Static_assert(TCM_N_AUX <= TCM_MAX_AUX, "too many aux inputs for the runtime");
_Static_assert(TCM_N_AXES >= 1u && TCM_N_AXES <= TCM_MAX_AXES, "axis count out of range");
_Static_assert(TCM_N_STATES <= TCM_MAX_STATES, "too many filter states for the runtime");
_Static_assert(TCM_AXIS0_N_TERMS == TCM_N_TERMS, "axes' term counts do not add up");
_Static_assert(TCM_CODE_MIN <= TCM_CH0_MIN_CODE && TCM_CH0_MIN_CODE <= TCM_CH0_MAX_CODE && \
TCM_CH0_MAX_CODE <= TCM_CODE_MAX,
               "channel 0 (T01): range outside the 19-bit code range");
_Static_assert(TCM_CH0_MIN_CODE <= TCM_CH0_WINDOW_LO && TCM_CH0_WINDOW_LO <= TCM_CH0_WINDOW_HI \
&& TCM_CH0_WINDOW_HI <= TCM_CH0_MAX_CODE,
               "channel 0 (T01): training window outside the valid range");
_Static_assert(TCM_CH0_MAX_STEP >= 1, "channel 0 (T01): plausible step must be at least 1 code");
_Static_assert(TCM_CH0_MAX_STILL == 0u || (TCM_CH0_MAX_STILL >= 2u && TCM_CH0_MAX_STILL <= \
65535u), "channel 0 (T01): stuck limit must be 0 (off) or 2..65535 samples");

/* ---- Tables --------------------------------------------------------------------------- */
static const tcm_channel_t tcm_channels[] = {{
    {{.min_code = TCM_CH0_MIN_CODE, .max_code = TCM_CH0_MAX_CODE, \
.window_lo_code = TCM_CH0_WINDOW_LO, .window_hi_code = TCM_CH0_WINDOW_HI, \
.max_step_code = TCM_CH0_MAX_STEP, .max_still_samples = TCM_CH0_MAX_STILL, \
.tc_type = TCM_TC_K, .sensor = "T01"}},
}};
_Static_assert(sizeof tcm_channels / sizeof tcm_channels[0] == TCM_N_CHANNELS, \
"channel table size");

static const tcm_term_t tcm_terms[] = {{
    /* axis 0 (dz_um) term 0: temp channel 0 (T01) */
    {{.kind = TCM_KIND_TEMP, .input = 0u, .state = 0u, .param = TCM_AXIS0_TERM0_PARAM, \
.coef_q = TCM_AXIS0_TERM0_COEF_Q}},
}};
_Static_assert(sizeof tcm_terms / sizeof tcm_terms[0] == TCM_N_TERMS, "term table size");

static const tcm_axis_t tcm_axes[] = {{
    {{.shift = TCM_AXIS0_SHIFT, .n_terms = TCM_AXIS0_N_TERMS, \
.intercept_q = TCM_AXIS0_INTERCEPT_Q, .max_step_nm = TCM_AXIS0_MAX_STEP_NM, \
.service = {{.q_q8 = TCM_AXIS0_SVC_Q_Q8, \
.r_q8 = TCM_AXIS0_SVC_R_Q8, .floor2_nm2 = TCM_AXIS0_SVC_FLOOR2_NM2, \
.pmax_q8 = TCM_AXIS0_SVC_PMAX_Q8, .g2_q8 = TCM_AXIS0_SVC_G2_Q8, .on = TCM_AXIS0_SVC_ON, \
.p0_pmax = TCM_AXIS0_SVC_P0_PMAX, .reopen_after = TCM_AXIS0_SVC_REOPEN_AFTER}}, \
.name = "dz_um"}},
}};
_Static_assert(sizeof tcm_axes / sizeof tcm_axes[0] == TCM_N_AXES, "axis table size");

static const tcm_model_t tcm_model = {{
    .n_channels = TCM_N_CHANNELS,
    .n_aux = TCM_N_AUX,
    .n_axes = TCM_N_AXES,
    .n_terms = TCM_N_TERMS,
    .n_states = TCM_N_STATES,
    .period_ms = TCM_SAMPLE_PERIOD_MS,
    .channels = tcm_channels,
    .aux = NULL,
    .terms = tcm_terms,
    .axes = tcm_axes,
}};

/* The model, for callers that prefer a function (also keeps tcm_model "used"). */
static inline const tcm_model_t *tcm_model_get(void) {{ return &tcm_model; }}

#endif /* TCM_GENERATED_MODEL_H */
"""


def test_terms_of_one_sensor_and_time_constant_share_a_filter_state():
    gen = codegen.generate(model("shared_filters"))
    filters = [t for ax in gen.model.axes for t in ax.terms if t.kind in ("lag", "rate")]
    assert len(filters) == 7 and gen.model.n_states == 3
    # numbered in table order of first use: lag(T01,600) 0, lag(T02,600) 1, lag(T01,3600) 2;
    # the rate of T01 at 600 s is T - that lag, so it reads state 0
    assert [t.state for t in filters] == [0, 1, 2, 0, 2, 1, 1]
    assert "#define TCM_N_STATES 3u" in gen.text
    # 33 filter terms (one more than the box's 32 states), 11 distinct: the same 11 lags on
    # each of three axes cost 11 states
    lags = [term(make_lag("T01", 10.0 + i, 1.0), 0.01) for i in range(11)]
    pool = _single(lags)
    pool["axes"]["dy_um"] = {"unit": "um", "intercept": 0.0, "terms": lags}
    pool["axes"]["dx_um"] = {"unit": "um", "intercept": 0.0, "terms": lags}
    assert codegen.generate(pool).model.n_states == 11
    check_model(pool)  # the model file's check counts the same way


def test_golden_header_of_the_one_term_model():
    m = model("one_term")
    expected = GOLDEN.format(version=codegen.CODEGEN_VERSION, hash=codegen.model_hash(m),
                             crc=f"0x{_one_term_crc():08X}")
    assert codegen.generate(m).text == expected


# ---- determinism ----------------------------------------------------------------------------

def test_same_model_gives_identical_bytes_whatever_the_key_order(tmp_path):
    m = model("all_kinds")
    reordered = dict(reversed(list(copy.deepcopy(m).items())))
    for ax in reordered["axes"].values():
        for t in ax["terms"]:
            t_items = list(t.items())
            t.clear()
            t.update(reversed(t_items))
    a, b = codegen.generate(m).text, codegen.generate(reordered).text
    assert a == b
    assert not re.search(r"\d{4}-\d{2}-\d{2}|\d{2}:\d{2}:\d{2}", a)  # no timestamp
    for i in range(2):
        p = tmp_path / f"m{i}.json"
        p.write_text(json.dumps(m))
        codegen.write_header(p, tmp_path / f"m{i}.h")
    assert (tmp_path / "m0.h").read_bytes() == (tmp_path / "m1.h").read_bytes()


# ---- refusals: a clear message and nothing written ------------------------------------------

def _single(terms: list[dict], lo: float = -40.0, hi: float = 200.0, **kw) -> dict:
    m = base(channels=[channel(0, "T01", lo, hi)], **kw)
    m["axes"]["dz_um"] = {"unit": "um", "intercept": 0.0, "terms": terms}
    return m


def _edit(m: dict, fn) -> dict:
    m = copy.deepcopy(m)
    fn(m)
    return m


GOOD = _single([term(make_temp("T01"), 1.0)])
REFUSALS = [
    # tau 1e5 s at 1 s: state error 5000 nm/degC * 2^-23 degC * 0.5/alpha(1e-5) ~ 0.03 um.
    ("bound", _single([term(make_lag("T01", 1e5, 1.0), 5.0)]),
     ["axis 'dz_um'", "lag(T01, tau=100000s)", "5.0 um/degC", "exceeds --max-error-um 0.01",
      "state quantisation"]),
    ("unrepresentable", _single([term(make_temp("T01"), 1e300)]),
     ["axis 'dz_um'", "term 0 temp(T01)", "1e+300", "cannot be represented", "2^62"]),
    ("output overflow", _single([term(make_temp("T01"), 1e5)]),
     ["axis 'dz_um'", "2e+07 um", "int32", "term 0 temp(T01)", "100000.0 um/degC"]),
    ("intercept", _edit(GOOD, lambda m: m["axes"]["dz_um"].update(intercept=1e300)),
     ["axis 'dz_um'", "intercept", "cannot be represented"]),
    ("alpha", _single([{"kind": "lag", "source": "T01", "tau_s": 1000.0, "alpha": 0.001,
                        "coef": 1.0}]),
     ["lag(T01, tau=1000s)", "alpha 0.001", "multiple of 2^-30"]),
    ("square ref", _single([{"kind": "square", "source": "T01", "ref_c": 20.001,
                             "coef": 1.0}]),
     ["square(T01-20.001C)", "multiple of 1/128"]),
    ("source", _single([term(make_temp("T99"), 1.0)]), ["'T99'", "is not in 'channels'"]),
    ("kind", _single([{"kind": "cubic", "source": "T01", "coef": 1.0}]),
     ["unknown term kind 'cubic'"]),
    ("tc type", _edit(GOOD, lambda m: m["channels"][0].update(tc_type="T")),
     ["channels[0] (T01)", "'T'", "not supported"]),
    ("range", _single([term(make_temp("T01"), 1e-3)], hi=3000.0),
     ["channels[0] (T01)", "384000", "19-bit", "262143"]),
    ("channel index", _edit(GOOD, lambda m: m["channels"][0].update(channel=2)),
     ["channels", "0..0", "[2]"]),
    ("period", _edit(GOOD, lambda m: m.update(sample_period_s=0.0005)),
     ["sample_period_s", "0.0005", "whole number of milliseconds"]),
    ("states", _single([term(make_lag("T01", 10.0 + i, 1.0), 0.01) for i in range(33)]),
     ["33 distinct lag/rate filters", "32"]),
    ("name", _edit(GOOD, lambda m: (m["channels"][0].update(sensor="T,1"),
                                    m["axes"]["dz_um"]["terms"][0].update(source="T,1"))),
     ["channels[0].sensor", "'T,1'"]),
    # alpha = 1 (tau -> 0) over -200..1800 degC: |d*a| <= 256000*2^16*2^30 = 2^64.0 > 2^62.
    ("filter product", _single([{"kind": "rate", "source": "T01", "tau_s": 0.01,
                                 "alpha": 1.0, "coef": 1e-3}], lo=-200.0, hi=1800.0),
     ["rate(T01, tau=0.01s)", "filter update", "> 2^62"]),
    ("schema", _edit(GOOD, lambda m: m.update(schema="thermal-model/2")),
     ["schema 'thermal-model/2'"]),
    ("time without range", _edit(_single([{"kind": "time", "coef": 1e-4}]),
                                 lambda m: m.pop("time_max_s")),
     ["time", "time_max_s"]),
    ("no axes", _edit(GOOD, lambda m: m.update(axes={})), ["no axes"]),
    ("empty training range",
     _edit(GOOD, lambda m: m["channels"][0].update(trained_min_c=30.0, trained_max_c=20.0)),
     ["channels[0] (T01)", "training range 30..20", "empty"]),
    ("training range not a number",
     _edit(GOOD, lambda m: m["channels"][0].update(trained_min_c="cold", trained_max_c=20.0)),
     ["channels[0].trained_min_c", "'cold'"]),
]


@pytest.mark.parametrize("t_lo, t_hi, lo_c, hi_c", [
    (10.0, 40.0, -40.0, 200.0),  # span 30: window 8.5 .. 41.5 degC, exact codes
    (18.3, 41.7, -40.0, 200.0),  # not on a code boundary: rounded outwards
    (-19.0, 119.5, -20.0, 120.0),  # wider than the valid range: clipped to it
    (25.0, 25.0, -40.0, 200.0),  # constant in training: the window is that code's span
])
def test_training_window_codes_follow_the_documented_rule(t_lo, t_hi, lo_c, hi_c):
    m = _edit(GOOD, lambda m: m["channels"][0].update(trained_min_c=t_lo, trained_max_c=t_hi,
                                                      min_c=lo_c, max_c=hi_c))
    ch = codegen.generate(m).model.channels[0]
    lo, hi = math.ceil(Fraction(lo_c) * 128), math.floor(Fraction(hi_c) * 128)
    margin = (Fraction(t_hi) - Fraction(t_lo)) / 20
    want_lo = min(max(math.floor((Fraction(t_lo) - margin) * 128), lo), hi)
    want_hi = max(min(math.ceil((Fraction(t_hi) + margin) * 128), hi), lo)
    assert (ch.window_lo_code, ch.window_hi_code) == (want_lo, want_hi)
    if (t_lo, t_hi) == (10.0, 40.0):
        assert (ch.window_lo_code, ch.window_hi_code) == (1088, 5312)  # 8.5 * 128, 41.5 * 128
    # the model hash covers the window: another training range is another model
    assert codegen.model_hash(m) != codegen.model_hash(GOOD)


@pytest.mark.parametrize("label, bad, fragments", REFUSALS, ids=[r[0] for r in REFUSALS])
def test_refusals_name_what_is_wrong_and_write_nothing(label, bad, fragments, tmp_path):
    codegen.generate(GOOD)  # the unedited model is fine
    with pytest.raises(codegen.CodegenError) as err:
        codegen.generate(bad)
    for frag in fragments:
        assert frag in str(err.value), f"{label}: {frag!r} not in: {err.value}"
    assert isinstance(err.value, ValueError)
    path = tmp_path / "model.json"
    path.write_text(json.dumps(bad))
    before = path.read_bytes()
    with pytest.raises(codegen.CodegenError, match=str(path)):
        codegen.write_header(path, tmp_path / "model.h")
    assert not (tmp_path / "model.h").exists()
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.json"]  # no temp files


def test_a_looser_limit_accepts_the_refused_lag():
    bad = REFUSALS[0][1]
    gen = codegen.generate(bad, max_error_um=0.05)
    assert 0.01 < gen.fixed_point["axes"]["dz_um"]["bound_um"] <= 0.05


def test_invalid_json_is_reported_with_line_and_column(tmp_path):
    p = tmp_path / "model.json"
    p.write_text('{"schema": "thermal-model/1",\n  "axes": }\n')
    with pytest.raises(codegen.CodegenError, match=r"model.json, line 2, column 11"):
        codegen.write_header(p, tmp_path / "model.h")


# ---- write_header / CLI -----------------------------------------------------------------

def test_write_header_never_rewrites_the_model_and_puts_the_block_beside_the_header(tmp_path):
    m = model("all_kinds")
    m["axes"]["dx_um"]["metrics"] = {"train_rmse_um": 0.8}
    p = tmp_path / "model.json"
    p.write_text(json.dumps(m))
    before = p.read_bytes()
    gen_written = codegen.write_header(p, tmp_path / "build" / "model.h")
    out = tmp_path / "build" / "model.h"
    gen = codegen.generate(m)
    assert out.read_text() == gen.text == gen_written.text
    assert p.read_bytes() == before  # the user's model.json is only read
    fp = json.loads(codegen.fixed_point_path(out).read_text())
    assert codegen.fixed_point_path(out) == tmp_path / "build" / "model.h.json"
    assert codegen.model_hash(m) == fp["model_hash"]
    assert fp["crc32"] == f"0x{gen.crc32:08X}"
    for b in gen.bounds:
        ax = fp["axes"][b.axis]
        assert ax["bound_um"] == b.bound_um
        assert ax["bound_um"] >= ax["coef_quantisation_um"] + ax["state_quantisation_um"] \
            + ax["final_rounding_um"] - 1e-18
        assert ax["final_rounding_um"] == 0.0005 and ax["bound_um"] <= 0.01
    # A model that carries a fixed_point block (host train's) gives the same header.
    p.write_text(json.dumps({**m, "fixed_point": fp}))
    codegen.write_header(p, tmp_path / "again.h")
    assert (tmp_path / "again.h").read_text() == gen.text


def test_cli_writes_the_header_and_a_failed_bound_check_exits_1(tmp_path, capsys):
    p = tmp_path / "model.json"
    p.write_text(json.dumps(model("one_term")))
    assert host_main(["codegen", str(p)]) == 0
    assert (tmp_path / "model.h").read_text() == codegen.generate(model("one_term")).text
    assert "error bound 0.000500 um" in capsys.readouterr().out
    assert host_main(["codegen", str(p), "-o", str(tmp_path / "x.h"),
                      "--max-error-um", "0.0004"]) == 1  # a check failed (host/cli.py)
    err = capsys.readouterr().err
    assert "check failed" in err and "axis 'dz_um'" in err
    assert "0.0004" in err and "final rounding" in err
    assert not (tmp_path / "x.h").exists()


# ---- step limits (issue 14) and ZERO at power-up (issue 13) -----------------------------------

def test_step_limits_round_up_to_whole_codes_and_nanometres():
    m = model("one_term")
    m["channels"][0]["max_step_c"] = 0.3  # 38.4 codes -> 39 (never tighter than training)
    m["axes"]["dz_um"]["max_step_um"] = 2.0001  # 2000.1 nm -> 2001
    gen = codegen.generate(m)
    assert gen.model.channels[0].max_step_code == 39
    assert gen.model.axes[0].max_step_nm == 2001
    assert "#define TCM_CH0_MAX_STEP INT32_C(39)" in gen.text
    assert "#define TCM_AXIS0_MAX_STEP_NM INT32_C(2001)" in gen.text
    fp = gen.fixed_point
    assert fp["channels"][0]["max_step_code"] == 39
    assert fp["channels"][0]["max_step_source"] == "model"
    assert fp["axes"]["dz_um"]["max_step_nm"] == 2001
    assert fp["axes"]["dz_um"]["max_step_source"] == "model"
    # the limits are in the CRC: another limit, another CRC (and another model hash)
    other = copy.deepcopy(m)
    other["axes"]["dz_um"]["max_step_um"] = 2.5
    assert codegen.generate(other).crc32 != gen.crc32
    assert codegen.model_hash(other) != codegen.model_hash(m)


def test_a_model_without_step_limits_gets_the_documented_defaults():
    """docs/codegen.md: max(1 degC, 0.1 degC/s x period) per channel, 1 um/s x period per axis;
    recorded as 'default' and said in the header."""
    for period, code, nm in ((1.0, 128, 1000), (15.0, 192, 15000), (60.0, 768, 60000)):
        m = model("one_term")
        m["sample_period_s"] = period
        gen = codegen.generate(m)
        assert gen.model.channels[0].max_step_code == code
        assert gen.model.axes[0].max_step_nm == nm
        assert gen.fixed_point["channels"][0]["max_step_source"] == "default"
        assert "the conservative default (model.json has no max_step_c)" in gen.text


@pytest.mark.parametrize("where, value", [("channel", 0.0), ("channel", -1.0),
                                          ("axis", 0.0), ("axis", "fast"), ("axis", True)])
def test_step_limits_that_are_not_positive_numbers_are_refused(where, value):
    m = model("one_term")
    if where == "channel":
        m["channels"][0]["max_step_c"] = value
    else:
        m["axes"]["dz_um"]["max_step_um"] = value
    key = "max_step_c" if where == "channel" else "max_step_um"
    with pytest.raises(codegen.CodegenError, match=key):
        codegen.generate(m)


def test_the_model_file_validator_names_a_bad_step_limit():
    from thermal_comp.contract.model_file import ModelFormatError, check_model

    m = model("one_term")
    m["channels"][0]["max_step_c"] = -0.5
    with pytest.raises(ModelFormatError, match=r"channels\[0\]\.max_step_c \(T01\).*positive"):
        check_model(m)
    m = model("one_term")
    m["axes"]["dz_um"]["max_step_um"] = float("nan")
    with pytest.raises(ModelFormatError, match="max_step_um"):
        check_model(m)


def test_zero_at_powerup_is_a_header_option(tmp_path, capsys):
    m = model("one_term")
    assert "#define TCM_ZERO_AT_POWERUP 0" in codegen.generate(m).text
    gen = codegen.generate(m, zero_at_powerup=True)
    assert "#define TCM_ZERO_AT_POWERUP 1" in gen.text
    assert gen.fixed_point["zero_at_powerup"] is True
    assert gen.crc32 == codegen.generate(m).crc32  # an option, not a table
    p = tmp_path / "model.json"
    p.write_text(json.dumps(m))
    assert host_main(["codegen", str(p), "--zero-at-powerup"]) == 0
    out = capsys.readouterr().out
    assert "ZERO at power-up" in out and "conservative defaults for T01, dz_um" in out
    assert "#define TCM_ZERO_AT_POWERUP 1" in (tmp_path / "model.h").read_text()


def test_host_derives_step_limits_from_the_training_runs(tmp_path):
    """4x the fastest change per sample (a gap of k periods counts as k samples), floors
    1/16 degC and 0.5 um; computed here with plain numpy."""
    from thermal_comp.host.fitting.step_limits import add_step_limits, fastest_step
    from thermal_comp.host.io import Run

    t = np.array([0.0, 1.0, 2.0, 4.0, 5.0])  # a 2 s gap between samples 2 and 3
    temp = np.array([20.0, 20.5, 20.5, 21.5, 21.5])  # 0.5 per sample, 1.0 over the gap
    flat = np.full(5, 30.0)
    # built directly: load_run refuses a file with a gap (issue 14) unless --fill-gaps fills it
    run = Run(str(tmp_path / "r.csv"), t, ["T01", "T02"], np.column_stack([temp, flat]),
              ["dz_um"], temp[:, None])
    assert fastest_step(temp, t, 1.0) == pytest.approx(0.5)
    m = base(channels=[channel(0, "T01"), channel(1, "T02")])
    m["axes"]["dz_um"] = {"unit": "um", "intercept": 1.0,
                          "terms": [term(make_temp("T01"), 3.0), term(make_temp("T02"), 1.0)]}
    add_step_limits(m, [run])
    assert m["channels"][0]["max_step_c"] == pytest.approx(4 * 0.5)
    assert m["channels"][1]["max_step_c"] == pytest.approx(1 / 16)  # constant: the floor
    assert m["axes"]["dz_um"]["max_step_um"] == pytest.approx(4 * 3.0 * 0.5)
    # stuck limits: 2 x the longest run of one code, at least 10. T01's codes 2560, 2624,
    # 2624, 2752, 2752: runs of 2; T02 one code over 0..5 s with the 2 s gap: 6 samples.
    assert m["channels"][0]["max_still_samples"] == 10  # 2 x 2 = 4: the floor
    assert m["channels"][1]["max_still_samples"] == 12
    codegen.generate(m)  # and codegen takes them


def test_longest_still_counts_gaps_and_ends_at_a_missing_reading():
    from thermal_comp.host.fitting.step_limits import longest_still

    t = np.arange(7.0)
    assert longest_still(np.array([1.0, 1.0, np.nan, 1.0, 1.0, 1.0, 2.0]), t, 1.0) == 3
    # the box's codes, not the floats: 1.0 is code 128, 1.004 and 1.008 are both 129
    assert longest_still(np.array([1.0, 1.004, 1.008]), t[:3], 1.0) == 2
    assert longest_still(np.array([5.0, 5.0]), np.array([0.0, 600.0]), 60.0) == 11
    assert longest_still(np.array([]), np.array([]), 1.0) == 0


def test_stuck_limit_goes_into_the_header_and_the_crc():
    m = model("one_term")
    without = codegen.generate(m)
    assert without.model.channels[0].max_still_samples == 0
    assert "#define TCM_CH0_MAX_STILL 0u" in without.text
    assert "no stuck check (model.json has no max_still_samples)" in without.text
    m["channels"][0]["max_still_samples"] = 12
    gen = codegen.generate(m)
    assert gen.model.channels[0].max_still_samples == 12
    assert "#define TCM_CH0_MAX_STILL 12u" in gen.text
    assert gen.fixed_point["channels"][0]["max_still_samples"] == 12
    other = copy.deepcopy(m)
    other["channels"][0]["max_still_samples"] = 13
    crcs = {without.crc32, gen.crc32, codegen.generate(other).crc32}
    assert len(crcs) == 3  # in the CRC
    assert codegen.model_hash(other) != codegen.model_hash(m) != codegen.model_hash(
        model("one_term"))


@pytest.mark.parametrize("value", [0, 1, 65536, -3, 12.0, "12", True, None])
def test_a_stuck_limit_that_is_not_a_whole_number_of_samples_is_refused(value):
    from thermal_comp.contract.model_file import ModelFormatError, check_model

    m = model("one_term")
    m["channels"][0]["max_still_samples"] = value
    with pytest.raises(ModelFormatError,
                       match=r"channels\[0\]\.max_still_samples \(T01\).* 2 to 65535"):
        check_model(m)
    with pytest.raises(codegen.CodegenError, match="max_still_samples"):
        codegen.generate(m)


# ---- the twin: filter states, faults, every kind by hand ------------------------------------

def test_twin_kinds_cold_start_frozen_state_and_catch_up_by_hand():
    # alpha = 1/2 (a = 2^29). lag coef 1.28 um/degC -> 10 nm per code of the lagged value;
    # rate coef 2 um/degC; square 0.01 um/degC^2 about 20 degC; speed2 1e-6 um/rpm^2;
    # time 0.5 um/s saturating after 3 samples. One axis per term so each can be read alone.
    m = base(channels=[channel(0, "T01")],
             aux=[{"input": 0, "name": "rpm", "min": 0.0, "max": 12000.0}], time_max_s=3.0)
    lag = {"kind": "lag", "source": "T01", "tau_s": 1.4426950408889634, "alpha": 0.5}
    rate = {"kind": "rate", "source": "T01", "tau_s": 1.4426950408889634, "alpha": 0.5}
    for name, t in [("lag_um", {**lag, "coef": 1.28}), ("rate_um", {**rate, "coef": 2.0}),
                    ("sq_um", {"kind": "square", "source": "T01", "ref_c": 20.0,
                               "coef": 0.01}),
                    ("s2_um", {"kind": "speed2", "source": "rpm", "coef": 1e-6}),
                    ("time_um", {"kind": "time", "coef": 0.5})]:
        m["axes"][name] = {"unit": "um", "intercept": 0.0, "terms": [t]}
    fm = FixedModel.from_model(m)
    steps = [  # (code, valid, rpm) -> expected outputs (held where masked) and mask
        # 0: channel faulted from power-up: only speed2 and time computed.
        ((7, 0, 1000), [0, 0, 0, 1000, 0], 0b11000),
        # 1: first valid sample, 1000 codes: cold start s = 1000*2^16 -> lag 10000 nm,
        #    rate 0; square (1000-2560)^2/16384 degC^2 * 10 nm = 1485.3515625 -> 1485.
        #    rpm 12001 is out of range: speed2 held at 1000.
        ((1000, 1, 12001), [10000, 0, 1485, 1000, 500], 0b10111),
        # 2: 3000: s += (2000*2^16)/2 -> 2000 codes: lag 20000; rate (3000-2000)/128 degC
        #    * 2000 nm = 15625; square (440/128)^2 * 10 = 118.164... -> 118.
        ((3000, 1, 2000), [20000, 15625, 118, 4000, 1000], 0b11111),
        # 3: faulted, absurd code: lag/rate/square held, state frozen at 2000 codes.
        ((10**6, 1, 0), [20000, 15625, 118, 0, 1500], 0b11000),
        # 4: valid at 0 after a gap of one sample (docs/fixed-point.md, "Catch-up"): first
        #    the missed sample with the interpolated input 3000 + rdiv(-3000 * 1, 2) = 1500:
        #    s = 2000 + (1500 - 2000)/2 = 1750; then 0: s = 1750 - 1750/2 = 875 codes ->
        #    lag 8750; rate -875/128 * 2000 = -13671.875 -> -13672; square
        #    (2560/128)^2 * 10 = 4000. time saturates at 3 samples.
        ((0, 1, 12000), [8750, -13672, 4000, 144000, 1500], 0b11111),
    ]
    for i, ((code, valid, rpm), outs, mask) in enumerate(steps):
        assert fm.step([code], valid, [rpm]) == (outs, mask), f"step {i}"
    # The vectorised run agrees with the stepped one.
    codes = np.array([[s[0][0]] for s in steps])
    valid = np.array([[bool(s[0][1])] for s in steps])
    aux = np.array([[s[0][2]] for s in steps])
    out, ok = fm.evaluate_run(codes, aux, valid, return_mask=True)
    assert out.tolist() == [s[1] for s in steps]
    assert [int((row * (1 << np.arange(5))).sum()) for row in ok] == [s[2] for s in steps]


@pytest.mark.parametrize("a", [1, 3, 596523, 2**29, 2**30 - 1, 2**30])
def test_filter_state_stays_within_half_over_alpha_of_the_real_recursion(a):
    """The state quantisation claim, against the real-valued filter.

    The reference runs in 80-digit decimal: alpha = a/2^30 is exact there, and the rounding
    of 3000 steps on values below 2^35 stays under 1e-60 state units, far below the margin.
    """
    rng = np.random.default_rng(a)
    m = _single([{"kind": "lag", "source": "T01", "tau_s": 1.0, "alpha": a / 2**30,
                  "coef": 1e-6}])
    codes = np.cumsum(rng.integers(-300, 301, size=3000)).clip(-5120, 25600)
    codes[1000:1100] = 25600
    codes[1100:1200] = -5120
    fm = FixedModel.from_model(m)
    s = fm._filter_run(codes.tolist(), [True] * len(codes), a)
    assert s[0] == codes[0] * 65536  # cold start
    with decimal.localcontext() as ctx:
        ctx.prec = 80
        alpha = Decimal(a) / Decimal(2**30)
        y = Decimal(int(codes[0]) * 65536)
        worst = Decimal(0)
        for n in range(1, len(codes)):
            y += alpha * (Decimal(int(codes[n]) * 65536) - y)
            worst = max(worst, abs(Decimal(int(s[n])) - y))
        assert worst <= Decimal("0.5") / alpha
        if a == 2**30:
            assert worst == 0  # alpha = 1 follows the input exactly


def test_evaluate_run_equals_stepping_with_faults():
    fm = FixedModel.from_model(model("all_kinds"))
    rng = np.random.default_rng(7)
    n = 600
    codes = rng.integers(-6000, 26000, size=(n, 3))
    aux = rng.integers(-100, 12100, size=(n, 1))
    valid = rng.random((n, 3)) > 0.15
    out, ok = fm.evaluate_run(codes, aux, valid, return_mask=True)
    fm.reset()
    masks = (valid * (1 << np.arange(3))).sum(axis=1)
    stepped = [fm.step(codes[i].tolist(), int(masks[i]), aux[i].tolist()) for i in range(n)]
    assert out.tolist() == [s[0] for s in stepped]
    assert [int((r * (1 << np.arange(3))).sum()) for r in ok] == [s[1] for s in stepped]
    assert 0 < ok.sum() < ok.size  # both computed and held rows were exercised


def test_evaluate_run_rejects_non_integer_codes():
    fm = FixedModel.from_model(model("one_term"))
    with pytest.raises(ValueError, match="temp_to_code"):
        fm.evaluate_run(np.array([[25.0]]))
    with pytest.raises(ValueError, match="shape"):
        fm.evaluate_run(np.array([[1, 2]]))


def test_temp_to_code_rounds_to_nearest_lsb_like_the_chip():
    # 1/128 degC steps; ties (odd multiples of 1/256) go away from zero; 19-bit clip.
    assert temp_to_code(25.0) == 3200
    assert temp_to_code(1 / 256) == 1 and temp_to_code(-1 / 256) == -1
    assert temp_to_code(3 / 256) == 2 and temp_to_code(-3 / 256) == -2
    assert temp_to_code(0.0039) == 0 and temp_to_code(-0.0039) == 0
    assert temp_to_code(5000.0) == 2**18 - 1 and temp_to_code(-5000.0) == -(2**18)
    got = temp_to_code(np.array([[20.0, -40.0], [199.99, 200.0]]))
    assert got.dtype == np.int64 and got.tolist() == [[2560, -5120], [25599, 25600]]
    with pytest.raises(ValueError, match="NaN"):
        temp_to_code([1.0, float("nan")])


def test_export_to_c_gives_the_header_of_a_model_a_path_or_an_estimator(tmp_path):
    m = model("one_term")
    path = tmp_path / "model.json"
    path.write_text(json.dumps(m))
    text = codegen.export_to_c(m)
    assert text == codegen.generate(m).text and "#define" in text
    assert codegen.export_to_c(path) == text

    class Fitted:  # anything with to_model_json(), like host.train.estimator.ThermalModel
        def to_model_json(self):
            return m

    assert codegen.export_to_c(Fitted()) == text
    with pytest.raises(codegen.BoundError):
        codegen.export_to_c(m, max_error_um=0.0004)
