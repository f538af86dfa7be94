"""Writes the model header and the expected outputs the firmware's C application test checks.

Usage: gen_test_model.py OUT_DIR --clamp-nm N --slew-nm-per-s N --cold-start-slew 0|1
                         [--implausible-after N] [--zero-samples K]

The expectations come from the host, never from the firmware: the model is built with
contract.terms and rendered by codegen; the per-sample model outputs come from ``codegen.fixed``
(the integer twin of the runtime); channel validity, the plausibility guard, status bits, the
ZERO reference and the hold / step limit / clamp output stage are computed here from the rules
in docs/firmware.md and docs/protocol.md (written out again here, not taken from the twins of
codegen.fixed, so the C application test and the HIL check two independent statements).

Files: model_test.h (the header), model_bad.h (the same header with one table value changed
but its CRC macro kept: what a corrupted flash looks like to the box), vectors.h (inputs and
expected lines of a seeded session of N_SAMPLES periods).
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from fractions import Fraction
from pathlib import Path

import numpy as np

from thermal_comp import codegen
from thermal_comp.codegen.fixed import FixedModel
from thermal_comp.contract.terms import (
    make_lag,
    make_rate,
    make_speed,
    make_square,
    make_temp,
    make_time,
)

N_SAMPLES = 400
N_CHANNELS = 8
SEED = 20240605

# docs/protocol.md status bits
(MODEL_BAD, HOLD, SLEW, CLAMP, RANGE, OPEN, TC_FAULT, AUX_FAULT, WDT_RESET, NO_DATA, EXTRAP,
 REFERENCED, IMPLAUSIBLE, NO_REF, BEYOND) = (1 << i for i in range(15))
RUNAWAY_N = 4  # docs/firmware.md: the runaway check looks 4 readings back
BEYOND_SPAN, BEYOND_MIN_CODES = Fraction(1, 2), 640  # box_config.h defaults
ZERO_BEFORE = (128, 334)  # the CNC side sends ZERO before these samples (no axis holds)
SR_OPEN = 0x01
STILL_T07 = 12  # T07's max_still_samples: its code 12 samples in a row is STUCK


def term(t, coef: float) -> dict:
    return {**t.to_json(), "coef": coef}


def test_model(period: float = 1.0) -> dict:
    """8 channels (two type J, one narrow range), a spindle input, 3 axes using every kind."""
    channels = [{"channel": i, "sensor": f"T0{i + 1}", "tc_type": "J" if i in (2, 5) else "K",
                 "min_c": 0.0 if i == 3 else -40.0, "max_c": 100.0 if i == 3 else 200.0}
                for i in range(N_CHANNELS)]
    # T01 was trained between 10 and 40 degC (window 8.5..41.5 degC): its +30 degC step below
    # leaves it, EXTRAP. The other channels have no training range (window = valid range).
    channels[0].update({"trained_min_c": 10.0, "trained_max_c": 40.0})
    # Plausible change per sample: 2 degC (the session's random walk has sigma 0.3 degC) on
    # every channel but T08, which has none and gets codegen's default (1 degC at 1 s).
    for c in channels[:7]:
        c["max_step_c"] = 2.0
    # Stuck check on T07 only (the others have none, as a model.json from before it): the
    # steady-state tests of test_app.c keep every other channel at one code for minutes.
    channels[6]["max_still_samples"] = STILL_T07
    m = {"schema": "thermal-model/1", "tool_version": "0.1.0", "sample_period_s": period,
         "channels": channels,
         "aux": [{"input": 0, "name": "spindle_rpm", "min": 0.0, "max": 12000.0}],
         "time_max_s": 7200.0, "axes": {}, "training": {"runs": ["firmware-test"]}}
    m["axes"]["dx_um"] = {"unit": "um", "intercept": -3.5, "terms": [
        term(make_temp("T01"), 1.8), term(make_lag("T02", 600.0, period), -1.2),
        term(make_rate("T03", 120.0, period), 3.0), term(make_square("T04", 25.0), 0.01),
        term(make_time(), 1e-4)]}
    m["axes"]["dy_um"] = {"unit": "um", "intercept": 2.0, "terms": [
        term(make_speed("spindle_rpm"), 2e-3),
        term(make_speed("spindle_rpm", squared=True), -1e-7),
        term(make_temp("T05"), 0.9), term(make_lag("T06", 300.0, period), 0.6)]}
    m["axes"]["dz_um"] = {"unit": "um", "intercept": -10.0, "terms": [
        term(make_temp("T07"), 2.5), term(make_rate("T08", 60.0, period), -4.0),
        term(make_lag("T01", 1800.0, period), 1.1)]}
    # Output step limits: dx 5 um, dz 3 um per sample; dy none (codegen's default, 1 um/s).
    m["axes"]["dx_um"]["max_step_um"] = 5.0
    m["axes"]["dz_um"]["max_step_um"] = 3.0
    # In-service estimator (MEAS) on dx and dy; dz has none (a model from before: OFF).
    for a in ("dx_um", "dy_um"):
        m["axes"][a]["service"] = dict(SERVICE)
    return m


# dx's and dy's service block: P capped at 4 um^2 (a model without a start reference starts
# there), probe noise 0.5 um, gate 4 sigma (4 sqrt(4.25) = 8.2 um) above a 3 um floor
SERVICE = {"q_um2_per_h": 0.36, "probe_noise_um": 0.5, "gate_sigma": 4.0,
           "gate_floor_um": 3.0, "p_max_um2": 4.0}


def meas_expectations() -> dict[str, int]:
    """docs/service.md's "Fixed point" steps written out again from the spec (not from
    codegen.estimator), for a reading at P = p_max (the test model has no start reference,
    so P starts at p_max and stays there): innovation +5000 nm (accepted), then +50 um (a
    chip on the artifact: refused by the gate, nothing changes)."""
    pmax = 4 * 10**6 * 256  # p_max_um2 * 1e6 nm^2 * 2^8
    r = 25 * 10**4 * 256  # (0.5 um)^2 = 250 000 nm^2, in Q8
    g2 = 16 * 256  # gate_sigma^2 in Q8
    floor2 = 3000 ** 2

    def rdiv16(v: int) -> int:  # half away from zero
        return (abs(v) + 2**15) // 2**16 * (1 if v >= 0 else -1)

    def gate_ok(nu: int, p: int) -> bool:
        return nu * nu * 2**16 <= g2 * (p + r) or nu * nu <= floor2

    nu1 = 5000
    assert gate_ok(nu1, pmax)
    k = (pmax * 2**16 + (pmax + r) // 2) // (pmax + r)
    bias1 = rdiv16(k * nu1)
    p1 = pmax - rdiv16(k * pmax)
    nu2 = 50000 - bias1  # the reading is the model's value + 50 um; the bias already counts
    assert not gate_ok(nu2, p1)
    # P grows by q per sample after the reading: q_um2_per_h (the float's exact value) *
    # 10^6 nm^2 * 2^8 * period / 3600 s, rounded half away from zero
    q_exact = Fraction(SERVICE["q_um2_per_h"]) * 10**6 * 256 / 3600
    q = math.floor(q_exact + Fraction(1, 2))
    # one sample later, a reading that agrees with the model + bias (innovation 0)
    p1t = min(p1 + q, pmax)
    k2 = (p1t * 2**16 + (p1t + r) // 2) // (p1t + r)
    p2 = p1t - rdiv16(k2 * p1t)
    # the lock-out (docs/service.md, "Re-opening"): the third refused reading in a row that
    # agrees with the first (their difference passes the gate; a +90 um one does not) is taken
    # as it is (bias + nu: the model + 50 um) with its variance, min(R, p_max) = R
    assert gate_ok(0, p1t) and not gate_ok(40000, p1t)
    reopen_bias = bias1 + nu2
    return {"VEC_MEAS_BIAS1": bias1, "VEC_MEAS_P1_NM2": (p1 + 128) // 256,
            "VEC_MEAS_REOPEN_BIAS": reopen_bias,
            "VEC_MEAS_REOPEN_P_NM2": (min(r, pmax) + 128) // 256,
            "VEC_MEAS_P1_TICK_NM2": (p1t + 128) // 256, "VEC_MEAS_P2_NM2": (p2 + 128) // 256,
            "VEC_MEAS_PMAX_NM2": pmax // 256, "VEC_MEAS_GATE_NU": nu2}


def session(rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Chip readings, fault registers, presence and spindle speed for each sample."""
    n = N_SAMPLES
    temp = 20.0 + np.cumsum(rng.normal(0.0, 0.3, (n, N_CHANNELS)), axis=0)
    temp[150:, 0] += 30.0  # a step: drives dx past the clamp
    temp[200:205, 4] = 210.0  # above T05's valid range: RANGE, dy holds
    temp[60:64, 3] = -3.0  # below T04's 0 degC minimum: RANGE, dx holds
    temp[10:20, 6] -= 80.0  # negative codes, still inside T07's range: implausible steps
    temp[260, 4] += 100.0  # a one-sample glitch of T05, inside its range: IMPLAUSIBLE, held
    codes = np.round(temp * 128.0).astype(np.int64)
    # T07 freezes (a stuck converter) for STILL_T07 + 3 samples, twice: its code of sample 29
    # on 30..44 (stuck from the 12th reading of the run, 40..44: dz holds), then moves again;
    # and its code of 194 on 195..209 (stuck 205..209), across the warm reset of test_app.c
    # at 201, which must keep the count.
    for start in (30, 195):
        codes[start:start + STILL_T07 + 3, 6] = codes[start - 1, 6]
    sr = np.zeros((n, N_CHANNELS), dtype=np.int64)
    sr[100:120, 2] = SR_OPEN
    sr[250:253, 5] = 0x40  # TC range
    sr[300, 7] = 0x02  # over/under voltage
    sr[310:312, 1] = 0x80 | SR_OPEN
    present = np.ones((n, N_CHANNELS), dtype=bool)
    present[320:325, 0] = False  # chip 0 stops answering (MISO reads 0xFF)
    aux = rng.integers(0, 12001, n)
    aux[0:3] = 13000  # spindle input out of range from power-up: dy has NO_DATA
    aux[350:356] = 13000  # above the spindle range: AUX_FAULT, dy holds
    aux_ok = np.ones(n, dtype=bool)
    aux_ok[370:372] = False  # the ADC did not convert
    return {"codes": codes, "sr": sr, "present": present, "aux": aux, "aux_ok": aux_ok}


def plausible_step_codes(model: dict, period_s: float) -> list[int]:
    """max_step_code per channel from the rule of docs/codegen.md: ceil(max_step_c * 128), or
    the default max(1 degC, 0.1 degC/s * period)."""
    out = []
    for c in model["channels"]:
        step_c = Fraction(c["max_step_c"]) if "max_step_c" in c else \
            max(Fraction(1), Fraction(1, 10) * Fraction(period_s))
        out.append(max(1, math.ceil(step_c * 128)))
    return out


def axis_step_nm(model: dict, period_s: float) -> list[int]:
    """max_step_nm per axis: ceil(max_step_um * 1000), or 1 um/s * period."""
    return [max(1, math.ceil(Fraction(ax["max_step_um"]) * 1000)) if "max_step_um" in ax
            else max(1, math.ceil(Fraction(period_s) * 1000)) for ax in model["axes"].values()]


def mean_half_away(total: int, n: int) -> int:
    q = (2 * abs(total) + n) // (2 * n)
    return q if total >= 0 else -q


def expected(model: dict, s: dict[str, np.ndarray], clamp: int, step: int,
             cold_start_slew: bool, fault_after: int = 3,
             zero_samples: int = 8) -> dict[str, np.ndarray]:
    twin = FixedModel.from_model(model)
    chans = twin.model.channels
    max_step = plausible_step_codes(model, model["sample_period_s"])
    track = axis_step_nm(model, model["sample_period_s"])
    # guard state per channel: last good, previous reading, implausible run, calm run, flags
    last = [0] * len(chans)
    prev = [0] * len(chans)
    bad = [0] * len(chans)
    calm = [0] * len(chans)
    has_ref = [False] * len(chans)
    faulted = [False] * len(chans)
    since = [0] * len(chans)  # samples since the last good reading
    recent: list[list[int]] = [[] for _ in chans]  # the latest consecutive readings
    # stuck check (docs/firmware.md): valid readings in a row with one code, and that code
    max_still = [c.get("max_still_samples", 0) for c in model["channels"]]
    still = [0] * len(chans)
    still_code = [0] * len(chans)
    stuck_samples = 0
    blocked = False  # an axis held (input fault) or walked at the previous sample: ZERO refused
    referenced = False
    aux_lo, aux_hi = twin.model.aux[0].min, twin.model.aux[0].max
    n_axes = twin.n_axes
    out = np.zeros((N_SAMPLES, n_axes), dtype=np.int64)
    status = np.zeros(N_SAMPLES, dtype=np.int64)
    shown = np.where(s["present"], s["codes"], 0)  # a silent chip reports code 0
    value = [0] * n_axes
    has = [False] * n_axes
    walking = [False] * n_axes
    ref = [0] * n_axes
    zero_n = [-1] * n_axes  # samples in the reference so far; -1: not averaging
    zero_sum = [0] * n_axes
    model_codes = np.where(s["present"], s["codes"], 0)
    for i in range(N_SAMPLES):
        bits = 0
        if i in ZERO_BEFORE:
            if blocked:
                raise SystemExit(f"gen_test_model: ZERO before sample {i} would be refused "
                                 "(an axis holds): move it")
            referenced = True
            zero_n = [0] * n_axes
            zero_sum = [0] * n_axes
        if referenced:
            bits |= REFERENCED
        valid_mask = 0
        for c, ch in enumerate(chans):
            code, sr = int(s["codes"][i, c]), int(s["sr"][i, c])
            in_range = False
            if not s["present"][i, c]:
                bits |= TC_FAULT
            elif sr:
                bits |= (OPEN if sr & SR_OPEN else 0) | (TC_FAULT if sr & ~SR_OPEN else 0)
            elif not ch.min_code <= code <= ch.max_code:
                bits |= RANGE
            else:
                in_range = True
            stuck = False
            if in_range:
                still[c] = still[c] + 1 if still[c] and code == still_code[c] else 1
                still_code[c] = code
                stuck = bool(max_still[c]) and still[c] >= max_still[c]
                stuck_samples += stuck
            else:
                still[c] = 0
            if not in_range or stuck:  # a fault: one more sample since the last good reading
                since[c] += 1 if has_ref[c] else 0
                recent[c], calm[c] = [], 0
                continue
            # the plausibility guard (docs/firmware.md): the allowance grows with the time
            # since the last good reading; 4 readings may move at most 3 limits
            verdict = "ok"
            run_away = len(recent[c]) == RUNAWAY_N and \
                abs(code - recent[c][0]) > max_step[c] * (RUNAWAY_N // 2 + 1)
            if has_ref[c]:
                since[c] += 1
                plausible = abs(code - last[c]) <= max_step[c] * since[c]
                if faulted[c]:
                    calm[c] = calm[c] + 1 if recent[c] and abs(code - prev[c]) <= max_step[c] \
                        else 0
                    prev[c] = code
                    ok = calm[c] >= fault_after and plausible and not run_away
                    recent[c] = (recent[c] + [code])[-RUNAWAY_N:]
                    verdict = "ok" if ok else "fault"
                elif plausible and run_away:
                    last[c], since[c], bad[c] = recent[c][0], RUNAWAY_N, 0
                    faulted[c], calm[c], prev[c] = True, 0, code
                    recent[c] = (recent[c] + [code])[-RUNAWAY_N:]
                    verdict = "fault"
                elif not plausible:
                    recent[c] = []
                    bad[c] += 1
                    verdict = "fault" if bad[c] >= fault_after else "held"
                    if verdict == "fault":
                        faulted[c], calm[c], prev[c], recent[c] = True, 0, code, [code]
            if verdict == "ok":
                last[c], has_ref[c], faulted[c], bad[c], calm[c] = code, True, False, 0, 0
                since[c] = 0
                recent[c] = (recent[c] + [code])[-RUNAWAY_N:]
            else:
                bits |= IMPLAUSIBLE
            if verdict == "held":
                code = last[c]
                model_codes[i, c] = code
            if verdict != "fault":
                # the training window, from docs/protocol.md: lo = floor((min - 5 % span) * 128)
                t_lo, t_hi = model["channels"][c].get("trained_min_c"), \
                    model["channels"][c].get("trained_max_c")
                if t_lo is not None:  # exact arithmetic, as the rule is stated
                    margin = (Fraction(t_hi) - Fraction(t_lo)) / 20
                    w_lo = math.floor((Fraction(t_lo) - margin) * 128)
                    w_hi = math.ceil((Fraction(t_hi) + margin) * 128)
                else:  # no training range: the window is the valid range
                    w_lo, w_hi = ch.min_code, ch.max_code
                # beyond what training supports: half the window's span more, >= 5 degC
                far = max(math.floor((w_hi - w_lo) * BEYOND_SPAN), BEYOND_MIN_CODES)
                if not w_lo - far <= code <= w_hi + far:
                    bits |= BEYOND
                    continue
                valid_mask |= 1 << c
                if not w_lo <= code <= w_hi:
                    bits |= EXTRAP
        aux = int(s["aux"][i]) if s["aux_ok"][i] else aux_lo - 1
        if not s["aux_ok"][i] or not aux_lo <= aux <= aux_hi:
            bits |= AUX_FAULT
        computed, ok_mask = twin.step([int(x) for x in model_codes[i]], valid_mask, [aux])

        def clamped(v: int) -> int:
            nonlocal bits
            if abs(v) > clamp:
                bits |= CLAMP
                return clamp if v > 0 else -clamp
            return v

        blocked = False
        for a in range(n_axes):
            if not (ok_mask >> a) & 1:
                blocked = True
                bits |= HOLD | (0 if has[a] else NO_DATA)
                walking[a] = walking[a] or has[a]
                out[i, a] = value[a]
                continue
            if 0 <= zero_n[a] < zero_samples:
                zero_sum[a] += computed[a]
                zero_n[a] += 1
                new_ref = mean_half_away(zero_sum[a], zero_n[a])
                if has[a]:  # the datum moves, the tool does not
                    value[a] = clamped(value[a] - (new_ref - ref[a]))
                ref[a] = new_ref
            target = clamped(computed[a] - ref[a])
            if not has[a]:
                has[a] = True
                if not cold_start_slew:
                    value[a] = target
                    out[i, a] = value[a]
                    continue
                walking[a] = True
            lim = min(step, track[a]) if walking[a] else track[a]
            if abs(target - value[a]) <= lim:
                value[a], walking[a] = target, False
            else:
                value[a] += lim if target > value[a] else -lim
                bits |= SLEW
                blocked = True  # walking: not the model's output, ZERO refused
            out[i, a] = value[a]
        status[i] = bits
    return {"out": out, "status": status, "shown": shown, "stuck_samples": stuck_samples}


def c_rows(a: np.ndarray) -> str:
    return ",\n".join("    {" + ", ".join(str(int(v)) for v in row) + "}" for row in a)


def c_list(a: np.ndarray) -> str:
    return ", ".join(str(int(v)) for v in a)


def corrupt(header: str) -> str:
    """Move axis 0's intercept one LSB towards zero: the tables change, the CRC macro not."""
    pat = re.compile(r"(#define TCM_AXIS0_INTERCEPT_Q INT64_C\()(-?\d+)(\))")
    m = pat.search(header)
    if m is None or int(m.group(2)) == 0:
        raise SystemExit("gen_test_model: no non-zero TCM_AXIS0_INTERCEPT_Q to corrupt")
    v = int(m.group(2))
    return pat.sub(f"\\g<1>{v - 1 if v > 0 else v + 1}\\g<3>", header, count=1)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--clamp-nm", type=int, required=True)
    ap.add_argument("--slew-nm-per-s", type=int, required=True)
    ap.add_argument("--cold-start-slew", type=int, choices=(0, 1), required=True)
    ap.add_argument("--implausible-after", type=int, default=3)
    ap.add_argument("--zero-samples", type=int, default=8)
    args = ap.parse_args(argv)

    model = test_model()
    gen = codegen.generate(model)
    period_ms = gen.model.period_ms
    step = max(1, (args.slew_nm_per_s * period_ms + 500) // 1000)
    s = session(np.random.default_rng(SEED))
    e = expected(model, s, args.clamp_nm, step, bool(args.cold_start_slew),
                 args.implausible_after, args.zero_samples)

    # The session must exercise what it claims to: every status bit it is built for.
    seen = int(np.bitwise_or.reduce(e["status"]))
    for bit, name in ((HOLD, "HOLD"), (SLEW, "SLEW"), (CLAMP, "CLAMP"), (RANGE, "RANGE"),
                      (OPEN, "OPEN"), (TC_FAULT, "TC_FAULT"), (AUX_FAULT, "AUX_FAULT"),
                      (NO_DATA, "NO_DATA"), (EXTRAP, "EXTRAP"), (REFERENCED, "REFERENCED"),
                      (IMPLAUSIBLE, "IMPLAUSIBLE")):
        if not seen & bit:
            raise SystemExit(f"gen_test_model: the test session never raises {name}")
    if e["stuck_samples"] != 10:  # 40..44 and 205..209
        raise SystemExit(f"gen_test_model: T07 is stuck on {e['stuck_samples']} samples, "
                         "the session is built for 10")

    axes = ";".join(gen.model.axes[a].name for a in range(len(gen.model.axes)))
    chmap = ";".join(f"{c.index}:{c.sensor}:{c.tc_type}" for c in gen.model.channels)
    zero_before = np.isin(np.arange(N_SAMPLES), ZERO_BEFORE).astype(int)
    meas = "\n".join(f"#define {k} {v}" for k, v in meas_expectations().items())
    out = args.out_dir
    out.mkdir(parents=True, exist_ok=True)
    (out / "model_test.h").write_text(gen.text)
    (out / "model_bad.h").write_text(corrupt(gen.text))
    (out / "vectors.h").write_text(f"""/* Generated by gen_test_model.py -- DO NOT EDIT.
 * Expectations from the host (codegen.fixed + the documented output rules), seed {SEED}. */
#ifndef TEST_VECTORS_H
#define TEST_VECTORS_H

#include <stdbool.h>
#include <stdint.h>

#define VEC_N {N_SAMPLES}
#define VEC_N_CHANNELS {N_CHANNELS}
#define VEC_N_AXES {len(gen.model.axes)}
#define VEC_PERIOD_MS {period_ms}u
#define VEC_MODEL_HASH "{gen.model.model_hash}"
/* INFO fields after the crc flag: period, axes, channel map */
#define VEC_INFO_TAIL "{period_ms},{axes},{chmap}"
#define VEC_CLAMP_NM {args.clamp_nm}
#define VEC_SLEW_NM_PER_S {args.slew_nm_per_s}
#define VEC_COLD_START_SLEW {args.cold_start_slew}
#define VEC_IMPLAUSIBLE_AFTER {args.implausible_after}
#define VEC_ZERO_SAMPLES {args.zero_samples}
/* channel 6 (T07) has a stuck check: its code this many readings in a row is STUCK */
#define VEC_STILL_CHANNEL 6
#define VEC_MAX_STILL {STILL_T07}

static const int32_t vec_codes[VEC_N][VEC_N_CHANNELS] = {{
{c_rows(s["codes"])}
}};
static const uint8_t vec_sr[VEC_N][VEC_N_CHANNELS] = {{
{c_rows(s["sr"])}
}};
static const bool vec_present[VEC_N][VEC_N_CHANNELS] = {{
{c_rows(s["present"].astype(int))}
}};
static const int32_t vec_aux[VEC_N] = {{{c_list(s["aux"])}}};
static const bool vec_aux_ok[VEC_N] = {{{c_list(s["aux_ok"].astype(int))}}};
/* expected: the temperature codes each line shows, the corrections and the status word */
static const int32_t vec_shown[VEC_N][VEC_N_CHANNELS] = {{
{c_rows(e["shown"])}
}};
static const int32_t vec_out_nm[VEC_N][VEC_N_AXES] = {{
{c_rows(e["out"])}
}};
static const uint16_t vec_status[VEC_N] = {{{c_list(e["status"])}}};
/* ZERO is sent before these samples */
static const bool vec_zero_before[VEC_N] = {{{c_list(zero_before)}}};

/* MEAS (docs/service.md): dx and dy run the estimator, dz has none; a reading +5 um above
 * the model at P = p_max, then +50 um (refused by the gate) */
#define VEC_SVC_IDLE "0:-:0:0;0:-:0:0;-"
{meas}

#endif
""")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
