"""The report of a replay and its judgement, apart from the checks that fill it in.

A box that matches its twin can still be useless or alarming, so the report carries the
judgement too (``Judging``): it fails when the box held (HOLD/NO_DATA) or limited (SLEW) more
than a stated share of the samples, or never corrected at all (a model trained in Kelvin: every
reading out of range, every sample held); and (issue 41, "never worse than no compensation")
when an axis's compensated error is larger than its raw error (RMS or peak), when the clamp
(CLAMP) engaged on more than a stated share of the samples, or when the output stepped by more
than the axis's step limit between two consecutive lines of a power-up. The report is what
``hil replay`` prints and writes as JSON; ``hil.checks`` fills it in.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from thermal_comp.hil.expect import CLAMP, HOLD, MODEL_BAD, NO_DATA, SLEW, STATUS_NAMES

MAX_PROBLEMS = 20  # detail lines kept in a report; counts are always complete


@dataclass(frozen=True)
class Judging:
    """How much holding and limiting a replay may show before it fails.

    The defaults: a box that holds (a faulted input, HOLD/NO_DATA) or limits its output step
    (SLEW: walking back or the per-axis limit) on more than 10 % of the samples of a run is
    not compensating that run, whatever its twin says; one that never corrects fails always.
    """

    max_held_fraction: float = 0.10
    max_limited_fraction: float = 0.10
    require_correction: bool = True
    # The clamp (BOX_MAX_CORRECTION_NM, 200 um) is the box's last resort: a sound model stays
    # far inside it. 1 % lets a short excursion be clamped (the output stays bounded, which is
    # the clamp's job) but not a model that lives at the bound (x50 coefficients: 99 %).
    max_clamped_fraction: float = 0.01
    # Compensation must not leave a larger error than no compensation (RMS or peak, per axis
    # with a measured displacement), and no output step may exceed the axis's step limit.
    require_no_worse: bool = True
    require_step_limit: bool = True


@dataclass
class AxisReport:
    name: str
    mismatches: int = 0
    max_abs_diff_nm: int = 0
    raw_rms_um: float | None = None
    raw_peak_um: float | None = None
    compensated_rms_um: float | None = None
    compensated_peak_um: float | None = None
    float_max_diff_um: float | None = None
    float_samples: int = 0
    bound_um: float | None = None
    max_step_nm: int | None = None  # the axis's step limit (header), None when unknown
    largest_step_nm: int | None = None  # largest output step between consecutive lines
    steps_over_limit: int = 0  # consecutive-line steps beyond max_step_nm
    first_step_over: int | None = None  # sample of the first of them

    def to_json(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "name"}

    def worse_than_raw(self) -> list[str]:
        """Which of RMS and peak the compensation made worse than the raw drift."""
        out = []
        if self.raw_rms_um is not None and self.compensated_rms_um is not None \
                and self.compensated_rms_um > self.raw_rms_um:
            out.append(f"RMS {self.compensated_rms_um:.3f} > raw {self.raw_rms_um:.3f}")
        if self.raw_peak_um is not None and self.compensated_peak_um is not None \
                and self.compensated_peak_um > self.raw_peak_um:
            out.append(f"peak {self.compensated_peak_um:.3f} > raw {self.raw_peak_um:.3f}")
        return out



@dataclass
class ReplayReport:
    samples: int
    received: int = 0
    mismatches: int = 0  # samples where a correction differs from the expectation
    status_mismatches: int = 0
    code_mismatches: int = 0
    max_abs_diff_nm: int = 0
    lost: int = 0
    duplicated: int = 0
    reordered: int = 0
    bad_lines: int = 0
    sessions: int = 1
    axes: dict[str, AxisReport] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)  # $E reasons received, in order
    fw_out_nm: np.ndarray | None = None  # (n, axes) what the box sent; missing rows = 0
    fw_status: np.ndarray | None = None  # (n,) status words; -1 where no line arrived
    fw_seq: np.ndarray | None = None  # (n,) seq of the line of each sample; -1 where none
    fw_session: np.ndarray | None = None  # (n,) session (power-up) of each sample's line
    judging: Judging | None = None
    elapsed_s: float | None = None
    problems_fatal: bool = False  # the replay itself broke (timeout, crash)
    extra_checks: dict[str, bool] = field(default_factory=dict)  # e.g. qemu_equals_native

    # MEAS (issue 42): per axis static / updated RMS, readings applied and refused
    service: dict[str, dict] = field(default_factory=dict)

    @property
    def float_ok(self) -> bool:
        return all(a.float_max_diff_um is None or a.bound_um is None
                   or a.float_max_diff_um <= a.bound_um + 1e-9 for a in self.axes.values())

    def _share(self, bits: int) -> float:
        """Share of the received samples whose status carries any of ``bits``."""
        if self.fw_status is None:
            return 0.0
        got = self.fw_status[self.fw_status >= 0]
        return float(np.mean((got & bits) != 0)) if got.size else 0.0

    @property
    def held_fraction(self) -> float:
        return self._share(HOLD | NO_DATA)

    @property
    def limited_fraction(self) -> float:
        return self._share(SLEW)

    @property
    def clamped_fraction(self) -> float:
        return self._share(CLAMP)

    @property
    def worse_axes(self) -> dict[str, list[str]]:
        """Axes whose compensated error exceeds the raw one, with what exceeds."""
        return {name: w for name, a in self.axes.items() if (w := a.worse_than_raw())}

    @property
    def step_axes(self) -> dict[str, AxisReport]:
        """Axes whose output stepped beyond their step limit between consecutive lines."""
        return {name: a for name, a in self.axes.items() if a.steps_over_limit}

    @property
    def corrected_samples(self) -> int:
        """Received samples on which every axis had its correction (no HOLD, NO_DATA or
        MODEL_BAD)."""
        if self.fw_status is None:
            return 0
        got = self.fw_status[self.fw_status >= 0]
        return int(np.count_nonzero((got & (HOLD | NO_DATA | MODEL_BAD)) == 0))

    @property
    def judgement(self) -> dict[str, bool]:
        j = self.judging
        if j is None:
            return {}
        out = {"held_within_limit": self.held_fraction <= j.max_held_fraction,
               "limited_within_limit": self.limited_fraction <= j.max_limited_fraction,
               "clamped_within_limit": self.clamped_fraction <= j.max_clamped_fraction}
        if j.require_correction:
            out["corrected"] = self.corrected_samples > 0
        if j.require_no_worse:
            out["no_worse_than_uncompensated"] = not self.worse_axes
        if j.require_step_limit:
            out["steps_within_limit"] = not self.step_axes
        return out

    @property
    def checks(self) -> dict[str, bool]:
        return {
            "twin_bit_exact": self.mismatches == 0 and self.status_mismatches == 0
            and self.code_mismatches == 0,
            "float_within_bound": self.float_ok,
            "no_lost_duplicated_reordered": self.lost == 0 and self.duplicated == 0
            and self.reordered == 0 and self.bad_lines == 0,
            **self.judgement,
            **self.extra_checks,
        }

    def judgement_reasons(self) -> list[str]:
        """Why the judgement failed, in words (empty when it passed)."""
        j, out = self.judging, []
        if j is None:
            return out
        counts = self.status_counts
        faults = ", ".join(f"{k} on {v}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1])
                           if k in ("RANGE", "OPEN", "TC_FAULT", "AUX_FAULT", "IMPLAUSIBLE",
                                    "MODEL_BAD"))
        received = int((self.fw_status >= 0).sum()) if self.fw_status is not None else 0
        if j.require_correction and received and self.corrected_samples == 0:
            out.append(f"the box never corrected: all {received} samples held"
                       + (f" ({faults})" if faults else "")
                       + "; readings outside their channels' valid range on every sample "
                       "point at a model trained in other units (Kelvin?) or a wiring fault")
        if self.held_fraction > j.max_held_fraction:
            out.append(f"the box held on {100 * self.held_fraction:.1f} % of the samples "
                       f"(HOLD/NO_DATA; limit {100 * j.max_held_fraction:g} %, "
                       f"--max-held-fraction)" + (f": {faults}" if faults else ""))
        if self.limited_fraction > j.max_limited_fraction:
            out.append(f"the box limited its output step on {100 * self.limited_fraction:.1f} % "
                       f"of the samples (SLEW; limit {100 * j.max_limited_fraction:g} %, "
                       "--max-limited-fraction): the model output changes faster than its "
                       "step limit")
        if self.clamped_fraction > j.max_clamped_fraction:
            out.append(f"the box clamped its output on {100 * self.clamped_fraction:.1f} % of "
                       f"the samples (CLAMP; limit {100 * j.max_clamped_fraction:g} %, "
                       "--max-clamped-fraction): the model asks for more than the box's "
                       "maximum correction; its coefficients or units are wrong")
        if j.require_no_worse:
            for name, what in self.worse_axes.items():
                out.append(f"axis {name}: the compensated error is worse than no compensation "
                           f"({', '.join(what)} um): the box makes this axis less accurate")
        if j.require_step_limit:
            for name, a in self.step_axes.items():
                out.append(f"axis {name}: the output stepped by up to {a.largest_step_nm} nm "
                           f"between consecutive samples, beyond its step limit "
                           f"{a.max_step_nm} nm ({a.steps_over_limit} times, first at sample "
                           f"{a.first_step_over}; a ZERO's change of datum not counted)")
        return out

    @property
    def status_counts(self) -> dict[str, int]:
        """Samples whose status word (as the box sent it) carries each bit."""
        if self.fw_status is None:
            return {}
        got = self.fw_status[self.fw_status >= 0]
        return {name: int(((got >> i) & 1).sum()) for i, name in enumerate(STATUS_NAMES)
                if ((got >> i) & 1).any()}

    @property
    def ok(self) -> bool:
        return all(self.checks.values()) and not self.problems_fatal

    def note(self, text: str) -> None:
        if len(self.problems) < MAX_PROBLEMS:
            self.problems.append(text)

    def to_json(self) -> dict:
        out = {
            "samples": self.samples,
            "mismatches": self.mismatches,
            **({"service": self.service} if self.service else {}),
            "max_abs_diff_nm": self.max_abs_diff_nm,
            "axes": {name: a.to_json() for name, a in self.axes.items()},
            "ok": self.ok,
            "checks": self.checks,
            "received": self.received,
            "status_mismatches": self.status_mismatches,
            "status_counts": self.status_counts,
            "held_fraction": round(self.held_fraction, 6),
            "limited_fraction": round(self.limited_fraction, 6),
            "clamped_fraction": round(self.clamped_fraction, 6),
            "corrected_samples": self.corrected_samples,
            "judging": None if self.judging is None else dict(self.judging.__dict__),
            "judgement_problems": self.judgement_reasons(),
            "code_mismatches": self.code_mismatches,
            "lost": self.lost,
            "duplicated": self.duplicated,
            "reordered": self.reordered,
            "bad_lines": self.bad_lines,
            "sessions": self.sessions,
            "problems": self.problems,
        }
        if self.elapsed_s is not None:
            out["elapsed_s"] = round(self.elapsed_s, 3)
            out["samples_per_s"] = round(self.samples / self.elapsed_s, 1) if self.elapsed_s \
                else None
        return out
