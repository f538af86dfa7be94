"""The integer twin of firmware/src/model_eval.c: the expectation for firmware and HIL tests.

Also the twins of the two pieces of the application around the model that decide what a
sample line carries: ``ChannelGuard`` (firmware/src/channel_guard.c, the plausibility guard)
and ``AxisOutput`` (firmware/src/axis_output.c: ZERO reference, hold, step limit, clamp),
sample for sample, call for call.

Same tables (``codegen.quantise``), same integer operations, same rounding (half away from
zero, never shifting a negative value), same filter cold start, same frozen state while a
channel is faulted, same treatment of out-of-range inputs as faults, same `time` counter.
``FixedModel.step`` mirrors ``tcm_step`` call for call; ``FixedModel.evaluate_run`` does a
whole run from power-up at numpy speed. Both are exact: Python ints in the recursions, and
int64 numpy only where docs/codegen.md proves no value can exceed 2^62.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from thermal_comp.codegen.quantise import QModel, QTerm, quantise
from thermal_comp.contract.fixed_point import (
    ALPHA_FRAC_BITS,
    CODE_MAX,
    CODE_MIN,
    STATE_FRAC_BITS,
    UINT32_MAX,
    div_round,
    rdiv,
)
from thermal_comp.contract.terms import AUX_KINDS, FILTER_KINDS, TEMPERATURE_KINDS

_STATE_ONE = 1 << STATE_FRAC_BITS
_ALPHA_HALF = 1 << (ALPHA_FRAC_BITS - 1)


def temp_to_code(temp_c):
    """degC -> the chip's code: nearest 1/128 degC (ties away from zero), clipped to 19 bits.

    Accepts a scalar (returns int) or an array (returns int64 array). NaN is refused: a
    missing reading is a fault, not a temperature.
    """
    x = np.asarray(temp_c, dtype=float)
    if np.isnan(x).any():
        raise ValueError("temp_to_code: NaN temperature (mark the channel invalid instead)")
    code = np.sign(x) * np.floor(np.abs(x) * 128.0 + 0.5)  # x*128 is exact in binary
    code = np.clip(code, CODE_MIN, CODE_MAX).astype(np.int64)
    return int(code) if code.ndim == 0 else code


def code_to_temp(codes) -> np.ndarray:
    """The temperature (degC) a code stands for: what the float model is fed in comparisons."""
    return np.asarray(codes, dtype=float) / 128.0


def _filter_update(s: int, target: int, a: int) -> int:
    p = (target - s) * a
    return s + ((p + _ALPHA_HALF) >> ALPHA_FRAC_BITS if p >= 0
                else -((-p + _ALPHA_HALF) >> ALPHA_FRAC_BITS))


# A filter whose channel came back after a gap of g samples is first run over the gap with
# inputs interpolated between its last valid reading and the new one (docs/fixed-point.md,
# "Catch-up"), at most CATCHUP_MAX samples: frozen over a long fault, its lag would lag by the
# whole change of the gap and then catch up after a datum (issue 41: 10 um off on dy).
CATCHUP_MAX = 65535


def _div_round(v: int, d: int) -> int:
    """v / d (d > 0) rounded half away from zero, as model_eval.c's tcm_div_round."""
    return (2 * v + d) // (2 * d) if v >= 0 else -((-2 * v + d) // (2 * d))


def _catch_up(s: int, last: int, code: int, gap: int, a: int) -> int:
    """The state after ``gap`` updates with inputs last + (code - last) * k / (gap + 1)."""
    g = min(gap, CATCHUP_MAX)
    for k in range(1, g + 1):
        s = _filter_update(s, (last + _div_round((code - last) * k, g + 1)) * _STATE_ONE, a)
    return s


def _rdiv_array(v: np.ndarray, f: int) -> np.ndarray:
    half = np.int64((1 << f) >> 1)
    return np.where(v >= 0, (v + half) >> f, -((-v + half) >> f))


class FixedModel:
    """Bit-exact Python model of the box's evaluation. ``step`` keeps state between calls."""

    def __init__(self, model: QModel) -> None:
        self.model = model
        self.terms: list[QTerm] = model.all_terms()
        self.n_channels = len(model.channels)
        self.n_aux = len(model.aux)
        self.n_axes = len(model.axes)
        self.reset()

    @classmethod
    def from_model(cls, model: Mapping) -> FixedModel:
        """From a model.json dict (validated and quantised exactly as codegen does)."""
        return cls(quantise(model))

    def reset(self) -> None:
        """Power-up: filters not started, counter 0, held outputs 0 (tcm_state_init)."""
        n_states = self.model.n_states
        self.s = [0] * n_states
        self.started = [False] * n_states
        self.last = [0] * n_states  # the last valid reading of each filter's channel
        self.gap = [0] * n_states  # samples missed since then (saturating)
        self.k = 0
        self.out = [0] * self.n_axes

    # ---- one sample, exactly tcm_step ----------------------------------------------------

    def _inputs_ok(self, temp_codes: Sequence[int], valid_mask: int,
                   aux: Sequence[int]) -> tuple[list[bool], list[bool]]:
        ch_ok = [bool((valid_mask >> c) & 1) and ch.min_code <= int(temp_codes[c]) <= ch.max_code
                 for c, ch in enumerate(self.model.channels)]
        aux_ok = [a.min <= int(aux[i]) <= a.max for i, a in enumerate(self.model.aux)]
        return ch_ok, aux_ok

    def _feature(self, t: QTerm, temp_codes: Sequence[int], aux: Sequence[int]) -> int:
        if t.kind == "temp":
            return int(temp_codes[t.input])
        if t.kind == "lag":
            return self.s[t.state]
        if t.kind == "rate":
            return int(temp_codes[t.input]) * _STATE_ONE - self.s[t.state]
        if t.kind == "speed":
            return int(aux[t.input])
        if t.kind == "speed2":
            return int(aux[t.input]) ** 2
        if t.kind == "square":
            return (int(temp_codes[t.input]) - t.param) ** 2
        if t.kind == "time":
            return min(self.k, t.param)
        raise AssertionError(t.kind)

    def step(self, temp_codes: Sequence[int], valid_mask: int | None = None,
             aux: Sequence[int] = ()) -> tuple[list[int], int]:
        """One sample: returns (outputs_nm, axes_mask). valid_mask None = all channels.

        outputs_nm holds, for an axis not in axes_mask, its last computed value (0 before the
        first): what a caller's out_nm buffer holds after tcm_step leaves it untouched.
        """
        if len(temp_codes) < self.n_channels or len(aux) < self.n_aux:
            raise ValueError(f"step needs {self.n_channels} temperature codes and "
                             f"{self.n_aux} aux values")
        if valid_mask is None:
            valid_mask = (1 << self.n_channels) - 1
        ch_ok, aux_ok = self._inputs_ok(temp_codes, valid_mask, aux)
        updated = set()
        for t in self.terms:  # filter states first, each once, at its first term in the table
            if t.kind not in FILTER_KINDS or t.state in updated:
                continue
            updated.add(t.state)
            i = t.state
            if ch_ok[t.input]:
                code = int(temp_codes[t.input])
                if not self.started[i]:
                    self.s[i], self.started[i] = code * _STATE_ONE, True
                else:
                    if self.gap[i]:
                        self.s[i] = _catch_up(self.s[i], self.last[i], code, self.gap[i],
                                              t.param)
                    self.s[i] = _filter_update(self.s[i], code * _STATE_ONE, t.param)
                self.last[i], self.gap[i] = code, 0
            elif self.started[i]:
                self.gap[i] = min(self.gap[i] + 1, 0xFFFF)  # uint16 on the box
        mask = 0
        for ax in self.model.axes:
            if all(ch_ok[t.input] for t in ax.terms if t.kind in TEMPERATURE_KINDS) and \
                    all(aux_ok[t.input] for t in ax.terms if t.kind in AUX_KINDS):
                acc = ax.intercept_q + sum(t.coef_q * self._feature(t, temp_codes, aux)
                                           for t in ax.terms)
                self.out[ax.index] = rdiv(acc, ax.shift)
                mask |= 1 << ax.index
        self.k = min(self.k + 1, UINT32_MAX)
        return list(self.out), mask

    # ---- a whole run from power-up, vectorised over samples ------------------------------

    def evaluate_run(self, temp_codes, aux=None, valid=None, return_mask: bool = False):
        """Outputs (nm, int64 [n, n_axes]) of a run fed to a freshly powered-up box.

        temp_codes: int [n, n_channels]; aux: int [n, n_aux] (may be None without aux);
        valid: bool [n, n_channels] (None = all flagged valid). An axis whose inputs are not
        all valid holds its previous output (0 before its first valid sample), exactly like
        calling ``step`` n times after ``reset``. ``return_mask`` also returns bool
        [n, n_axes], True where the axis was computed. Does not touch ``step``'s state.
        """
        codes = self._int_matrix(temp_codes, self.n_channels, "temp_codes")
        n = codes.shape[0]
        auxv = (np.zeros((n, 0), dtype=np.int64) if aux is None and self.n_aux == 0
                else self._int_matrix(aux, self.n_aux, "aux", n))
        flagged = (np.ones(codes.shape, dtype=bool) if valid is None
                   else np.asarray(valid, dtype=bool))
        if flagged.shape != codes.shape:
            raise ValueError(f"valid must have shape {codes.shape}, got {flagged.shape}")
        lo = np.array([c.min_code for c in self.model.channels], dtype=np.int64)
        hi = np.array([c.max_code for c in self.model.channels], dtype=np.int64)
        ch_ok = flagged & (codes >= lo) & (codes <= hi)
        alo = np.array([a.min for a in self.model.aux], dtype=np.int64)
        ahi = np.array([a.max for a in self.model.aux], dtype=np.int64)
        aux_ok = (auxv >= alo) & (auxv <= ahi)
        # Rows where an input is faulted are computed on an in-range stand-in and discarded,
        # so that no intermediate can leave the proven ranges.
        codes = np.where(ch_ok, codes, lo)
        auxv = np.where(aux_ok, auxv, alo)

        states = {}
        for t in self.terms:
            if t.kind in FILTER_KINDS and t.state not in states:
                states[t.state] = self._filter_run(codes[:, t.input].tolist(),
                                                   ch_ok[:, t.input].tolist(), t.param)
        k = np.minimum(np.arange(n, dtype=np.int64), UINT32_MAX)
        out = np.zeros((n, self.n_axes), dtype=np.int64)
        computed = np.zeros((n, self.n_axes), dtype=bool)
        for ax in self.model.axes:
            ok = np.ones(n, dtype=bool)
            acc = np.full(n, ax.intercept_q, dtype=np.int64)
            for t in ax.terms:
                if t.kind in TEMPERATURE_KINDS:
                    ok &= ch_ok[:, t.input]
                elif t.kind in AUX_KINDS:
                    ok &= aux_ok[:, t.input]
                acc += np.int64(t.coef_q) * self._feature_column(t, codes, auxv, states, k)
            value = _rdiv_array(acc, ax.shift)
            # Hold: each row takes the value of the latest computed row at or before it.
            last = np.maximum.accumulate(np.where(ok, np.arange(n), -1))
            out[:, ax.index] = np.where(last >= 0, value[np.maximum(last, 0)], 0)
            computed[:, ax.index] = ok
        return (out, computed) if return_mask else out

    @staticmethod
    def _filter_run(codes: list[int], ok: list[bool], a: int) -> np.ndarray:
        """The state after each sample's update (frozen while faulted, caught up over the gap
        when the channel comes back); exact Python ints."""
        s, started, res = 0, False, []
        last = gap = 0
        append = res.append
        for code, valid in zip(codes, ok, strict=True):
            if valid:
                target = code * _STATE_ONE
                if started:
                    if gap:
                        s = _catch_up(s, last, code, gap, a)
                    p = (target - s) * a
                    s += ((p + _ALPHA_HALF) >> ALPHA_FRAC_BITS if p >= 0
                          else -((-p + _ALPHA_HALF) >> ALPHA_FRAC_BITS))
                else:
                    s, started = target, True
                last, gap = code, 0
            elif started:
                gap += 1
            append(s)
        return np.array(res, dtype=np.int64)

    @staticmethod
    def _feature_column(t: QTerm, codes: np.ndarray, auxv: np.ndarray,
                        states: dict[int, np.ndarray], k: np.ndarray) -> np.ndarray:
        if t.kind == "temp":
            return codes[:, t.input]
        if t.kind == "lag":
            return states[t.state]
        if t.kind == "rate":
            return codes[:, t.input] * np.int64(_STATE_ONE) - states[t.state]
        if t.kind == "speed":
            return auxv[:, t.input]
        if t.kind == "speed2":
            return auxv[:, t.input] * auxv[:, t.input]
        if t.kind == "square":
            e = codes[:, t.input] - np.int64(t.param)
            return e * e
        if t.kind == "time":
            return np.minimum(k, np.int64(t.param))
        raise AssertionError(t.kind)

    @staticmethod
    def _int_matrix(values, width: int, name: str, n: int | None = None) -> np.ndarray:
        arr = np.asarray(values)
        if arr.ndim != 2 or arr.shape[1] != width or (n is not None and arr.shape[0] != n):
            want = f"({n if n is not None else 'n'}, {width})"
            raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
        if not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"{name} must be integers (temperatures: codegen.fixed."
                             "temp_to_code)")
        if arr.size and (arr.min() < -(1 << 31) or arr.max() > (1 << 31) - 1):
            raise ValueError(f"{name}: values must fit int32 like the box's inputs")
        return arr.astype(np.int64)


# ---- the application's plausibility guard and output stage ----------------------------------

GUARD_OK, GUARD_HELD, GUARD_FAULT = 0, 1, 2


GUARD_RUNAWAY_SAMPLES = 4  # channel_guard.h: readings of the runaway check


class ChannelGuard:
    """Twin of channel_guard.c: one channel's plausibility guard (docs/firmware.md)."""

    def __init__(self) -> None:
        self.last_good, self.prev, self.since, self.bad_run, self.calm = 0, 0, 0, 0, 0
        self.has_ref, self.faulted = False, False
        self.run: list[int] = []  # the latest consecutive readings, oldest first

    def _tick(self) -> None:
        self.since = min(self.since + 1, 65535)

    def lost(self) -> None:
        """The channel had no usable reading (chip fault, no answer, out of range)."""
        if self.has_ref:
            self._tick()
        self.run, self.calm = [], 0

    def _push(self, code: int) -> None:
        self.run = (self.run + [code])[-GUARD_RUNAWAY_SAMPLES:]

    def _runaway(self, code: int, max_step: int) -> bool:
        return (len(self.run) == GUARD_RUNAWAY_SAMPLES
                and abs(code - self.run[0]) > max_step * (GUARD_RUNAWAY_SAMPLES // 2 + 1))

    def _accept(self, code: int) -> tuple[int, int]:
        self.last_good, self.has_ref, self.faulted = code, True, False
        self.since, self.bad_run, self.calm = 0, 0, 0
        self._push(code)
        return GUARD_OK, code

    def _fault(self, code: int) -> tuple[int, int]:
        self.faulted, self.calm, self.prev = True, 0, code
        self._push(code)  # a runaway's readings stay: it must stop before recovery
        return GUARD_FAULT, code

    def check(self, code: int, max_step: int, fault_after: int) -> tuple[int, int]:
        """(verdict, code the model gets) for a reading that passed chip and range checks."""
        if max_step <= 0 or not self.has_ref:
            return self._accept(code)
        self._tick()
        allowed = max_step * self.since
        if self.faulted:
            self.calm = (min(self.calm + 1, 255) if self.run and abs(code - self.prev) <= max_step
                         else 0)
            ok = (self.calm >= fault_after and abs(code - self.last_good) <= allowed
                  and not self._runaway(code, max_step))
            self.prev = code
            self._push(code)
            return self._accept(code) if ok else (GUARD_FAULT, code)
        if abs(code - self.last_good) <= allowed:
            if self._runaway(code, max_step):
                self.last_good, self.since, self.bad_run = \
                    self.run[0], GUARD_RUNAWAY_SAMPLES, 0
                return self._fault(code)
            return self._accept(code)
        self.run = []
        self.bad_run += 1
        if self.bad_run >= fault_after:
            return self._fault(code)
        return GUARD_HELD, self.last_good


class AxisOutput:
    """Twin of axis_output.c for one axis: ZERO reference, hold, step limit, clamp.

    ``update`` returns the names of the status bits it raises (HOLD, SLEW, CLAMP, NO_DATA);
    ``out_nm`` is what the sample line carries afterwards, ``ref_nm`` the reference.
    """

    def __init__(self, max_abs_nm: int, walk_step_nm: int, track_step_nm: int,
                 zero_samples: int, cold_start_slew: bool) -> None:
        self.max_abs, self.walk_step, self.track_step = max_abs_nm, walk_step_nm, track_step_nm
        self.zero_samples, self.cold_start_slew = zero_samples, cold_start_slew
        self.out_nm, self.has_output, self.walking = 0, False, False
        self.zeroing, self.ref_nm, self.zero_n, self.zero_sum = False, 0, 0, 0

    def zero(self) -> None:
        self.zeroing, self.zero_n, self.zero_sum = True, 0, 0

    def _clamp(self, v: int, flags: set[str]) -> int:
        if v > self.max_abs or v < -self.max_abs:
            flags.add("CLAMP")
            return self.max_abs if v > 0 else -self.max_abs
        return v

    def update(self, valid: bool, computed_nm: int) -> set[str]:
        flags: set[str] = set()
        if not valid:
            flags.add("HOLD")
            if not self.has_output:
                flags.add("NO_DATA")
            else:
                self.walking = True
            return flags
        if self.zeroing:
            self.zero_sum += computed_nm
            self.zero_n += 1
            ref = div_round(self.zero_sum, self.zero_n)
            if self.zero_n >= self.zero_samples:
                self.zeroing = False
            if self.has_output:
                self.out_nm = self._clamp(self.out_nm - (ref - self.ref_nm), flags)
            self.ref_nm = ref
        target = self._clamp(computed_nm - self.ref_nm, flags)
        if not self.has_output:
            self.has_output = True
            if not self.cold_start_slew:
                self.out_nm = target
                return flags
            self.walking = True
        step = min(self.track_step, self.walk_step) if self.walking else self.track_step
        diff = target - self.out_nm
        if -step <= diff <= step:
            self.out_nm, self.walking = target, False
        else:
            self.out_nm += step if diff > 0 else -step
            flags.add("SLEW")
        return flags
