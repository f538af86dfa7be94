"""One HIL replay end to end: header → firmware → feed → box → expectation → report.

This is the library behind ``python -m thermal_comp.hil replay`` and the fault-scenario tests.
Everything the report calls "expected" comes from the host (the twin and the documented output
stage); the firmware only ever supplies the lines being judged.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from thermal_comp.codegen.fixed import FixedModel
from thermal_comp.contract.fixed_point import CODE_MAX, CODE_MIN
from thermal_comp.contract.model_file import ModelSpec
from thermal_comp.contract.protocol import MeasReply, ProtocolError, decode
from thermal_comp.hil.build import ModelBuild, build_firmware, prepare_header
from thermal_comp.hil.checks import Judging, ReplayReport, judge
from thermal_comp.hil.expect import (
    SR_OPEN,
    Expected,
    OutputConfig,
    aux_fault_value,
    expect_session,
    sr_timeline,
)
from thermal_comp.hil.feed import Feed, build_feed
from thermal_comp.hil.native import NativeBox
from thermal_comp.hil.runner import Box, Capture, ChipFault, Event, Meas, Zero, replay
from thermal_comp.host.fitting import Reference


@dataclass
class ReplaySetup:
    """Everything a replay needs, prepared once (tests reuse it across scenarios)."""

    build: ModelBuild
    feed: Feed
    twin: FixedModel
    binary: Path
    output: OutputConfig
    judging: Judging = field(default_factory=Judging)  # how much HOLD/SLEW fails a replay

    @property
    def model(self) -> dict:
        return self.build.model

    @property
    def spec(self) -> ModelSpec:
        """The model's function, typed (``model`` is the file's dict)."""
        return self.build.spec

    def bounds_um(self) -> dict[str, float]:
        return {a: self.build.bound_um(a) for a in self.feed.axes}


def default_build_dir(model_json: str | Path) -> Path:
    """``<model dir>/hil``: next to build/model.json when run from the Makefile."""
    return Path(model_json).resolve().parent / "hil"


def prepare(model_json: str | Path, data: str | Path, build_dir: str | Path | None = None,
            cflags: str = "", binary: str | Path | None = None,
            zero_at_powerup: bool | None = None, reference: str | None = None) -> ReplaySetup:
    """Generate the header, build the native firmware (unless ``binary``) and load the run.

    ``reference`` (``start``/``none``) judges the run that way instead of by the model's own
    reference, and the header zeroes at power-up to match unless ``zero_at_powerup`` says.
    A box zeroed at power-up outputs the change since then, which ``none`` cannot judge.
    """
    if reference is not None:
        Reference.of_kind(reference)  # a clear error for an unknown kind
        if zero_at_powerup is None:
            zero_at_powerup = reference == "start"
        elif zero_at_powerup and reference == "none":
            raise ValueError("--reference none judges the box's absolute output, but a box "
                             "zeroed at power-up outputs the change since then: drop one")
    build_dir = Path(build_dir) if build_dir is not None else default_build_dir(model_json)
    mb = prepare_header(model_json, build_dir, zero_at_powerup)
    output = OutputConfig.from_build(cflags)
    q = mb.generated.model
    output.check_fits(len(q.channels), len(q.axes), len(q.aux), str(model_json))
    exe = Path(binary) if binary is not None else build_firmware(mb.header_path, build_dir,
                                                                 "native", cflags)
    feed = build_feed(mb.spec, data, reference)
    return ReplaySetup(mb, feed, FixedModel(q), exe, output)


def expectations(setup: ReplaySetup, capture: Capture, events: Sequence[Event],
                 model_bad: bool = False) -> list[Expected]:
    """The host's expectation for every session of a capture."""
    codes = np.clip(np.asarray(capture.codes_fed, dtype=np.int64), CODE_MIN, CODE_MAX)
    codes = codes.reshape(capture.n_samples, setup.feed.codes.shape[1])
    faults = [(e.at, e.channel, e.sr) for e in events if isinstance(e, ChipFault)]
    sr = sr_timeline(capture.n_samples, codes.shape[1], faults)
    zeros = [e.at for e in events if isinstance(e, Zero)]
    # MEAS readings per sample they are sent before, marked when a ZERO went before them
    meas_at: dict[int, list[tuple[int, int, int, bool]]] = {}
    zero_seen: set[int] = set()
    for e in events:
        if isinstance(e, Zero):
            zero_seen.add(e.at)
        elif isinstance(e, Meas):
            meas_at.setdefault(e.at, []).append((e.axis, e.nm, e.seq, e.at in zero_seen))
    # A warm reset (wdt_reset) resumes the box where it was: its session continues the one
    # before it, so the expectation runs over every session since the last cold boot.
    spans: list[list[int]] = []
    for k, s in enumerate(capture.sessions):
        if k > 0 and (s.wdt_reset or s.resumed) and not model_bad:
            spans[-1].append(k)
        else:
            spans.append([k])
    # A resumed session (RESUME after a power cut, the backup SRAM kept) continues the one
    # before as if every channel read open, and no aux, for the samples the box was off (no
    # line; its RESUME runs them so: docs/firmware.md, "Never worse than no compensation").
    aux_all = setup.feed.aux.copy()
    for k, s in enumerate(capture.sessions):
        if k > 0 and s.resumed:
            prev = capture.sessions[k - 1]
            gap = slice(prev.first_sample + prev.n_fed, s.first_sample)
            codes[gap], sr[gap] = 0, SR_OPEN
            for i, a in enumerate(setup.twin.model.aux):
                aux_all[gap, i] = aux_fault_value(a)
    out: list[Expected] = []
    for span in spans:
        first = capture.sessions[span[0]]
        last = capture.sessions[span[-1]]
        start, stop = first.first_sample, last.first_sample + last.n_fed
        rows = slice(start, stop)
        local = [z - start for z in zeros if start <= z < stop]
        warm = [(capture.sessions[k - 1].first_sample + capture.sessions[k - 1].n_fed
                 if capture.sessions[k].resumed else capture.sessions[k].first_sample) - start
                for k in span[1:]]
        meas = {at - start: [(a, nm, seq - start, z) for a, nm, seq, z in ms]
                for at, ms in meas_at.items() if start <= at < stop
                or (at == stop and last is capture.sessions[-1])}
        exp = expect_session(setup.twin, codes[rows], aux_all[rows], sr[rows],
                             setup.output, wdt_reset=first.wdt_reset, model_bad=model_bad,
                             zero_before=local, zero_at_powerup=setup.build.zero_at_powerup,
                             warm_resets=warm, meas=meas,
                             meas_samples=setup.output.meas_samples)
        for j, k in enumerate(span):
            s = capture.sessions[k]
            rows_k = _rows(exp, s.first_sample - start, s.n_fed, start)
            if j == 0:  # the span's replies, in order, kept with its first session
                rows_k.meas_replies = exp.meas_replies
            out.append(rows_k)
    return out


def _rows(exp: Expected, lo: int, n: int, start: int) -> Expected:
    """One session's part of an expectation over several (a warm reset in between)."""
    sl = slice(lo, lo + n)
    return Expected(exp.out_nm[sl], exp.computed_nm[sl], exp.computed[sl], exp.status[sl],
                    exp.codes[sl], None if exp.model_codes is None else exp.model_codes[sl],
                    None if exp.ref_nm is None else exp.ref_nm[sl],
                    tuple(z + start for z in exp.zero_refused), (),
                    None if exp.bias_nm is None else exp.bias_nm[sl])


def run(setup: ReplaySetup, events: Sequence[Event] = (), model_bad: bool = False,
        quiet: bool = True, window: int = 256,
        start_box: Callable[[bool], Box] | None = None) -> tuple[ReplayReport, Capture]:
    """Replay the setup's run through the firmware and judge it."""
    retain = Path(tempfile.mkdtemp(prefix="hil-retain-")) / "bkpsram"

    def native(wdt: bool, battery: bool = False) -> Box:
        if not wdt and not battery:  # a cold boot: a power cut took the backup SRAM with it
            retain.unlink(missing_ok=True)
        return NativeBox(setup.binary, wdt_reset=wdt, retain=retain)

    if setup.build.zero_at_powerup and not any(isinstance(e, Zero) and e.at == 0
                                               for e in events):
        # a start-referenced box holds (NO_REF) until the CNC side sends ZERO: as at a job start
        events = [Zero(0), *events]
    t0 = time.perf_counter()
    capture = replay(setup.feed, start_box or native, events, window=window, quiet=quiet)
    elapsed = time.perf_counter() - t0
    # a deliberately corrupted model is expected to correct nothing
    judging = replace(setup.judging, require_correction=False) if model_bad else setup.judging
    report = judge(capture, expectations(setup, capture, events, model_bad), setup.feed,
                   setup.spec, setup.bounds_um(), judging,
                   [e.at for e in events if isinstance(e, Zero)],
                   box_zeroes=setup.build.zero_at_powerup)
    report.elapsed_s = elapsed
    if any(isinstance(e, Meas) for e in events):
        judge_service(report, setup, capture, events, model_bad)
    return report, capture


def judge_service(report: ReplayReport, setup: ReplaySetup, capture: Capture,
                  events: Sequence[Event], model_bad: bool = False) -> None:
    """MEAS (issue 42): every $M reply against the twin (codegen.estimator), and per axis the
    RMS of measured - output, static (the same replay without readings, on the host) and
    updated (with them: what the box sent when it matched), into ``report.service``."""
    exp = expectations(setup, capture, events, model_bad)
    want = [r for e in exp for r in e.meas_replies]
    got: list[MeasReply | str] = []
    for s in capture.sessions:
        for line in s.meas_replies:
            try:
                got.append(decode(line))  # type: ignore[arg-type]
            except ProtocolError as exc:
                got.append(str(exc))
    bad = [(k, g, w) for k, (g, w) in enumerate(zip(got, want, strict=False)) if g != w]
    if len(got) != len(want) or bad:
        report.status_mismatches += max(len(bad), 1)
        first = bad[0] if bad else (min(len(got), len(want)), "-", "-")
        report.note(f"MEAS: {len(got)} replies, {len(want)} expected, {len(bad)} differ; "
                    f"first: reply {first[0]}: box {first[1]}, twin {first[2]}")
    static = expectations(setup, capture, [e for e in events if not isinstance(e, Meas)],
                          model_bad)
    probes = [e for e in events if isinstance(e, Meas)]
    axes = setup.feed.axes
    svc: dict[str, dict] = {}
    for a, name in enumerate(axes):
        y = setup.feed.measured.get(name)
        if y is None or model_bad:
            continue
        upd = np.concatenate([e.out_nm[:, a] for e in exp]) / 1000.0
        sta = np.concatenate([e.out_nm[:, a] for e in static]) / 1000.0
        y = np.asarray(y, dtype=float)[:upd.size]
        ok = np.isfinite(y)
        mine = [r for r in want if r.axis == a]
        svc[name] = {
            "static_rmse_um": float(np.sqrt(np.mean((y[ok] - sta[ok]) ** 2))),
            "updated_rmse_um": float(np.sqrt(np.mean((y[ok] - upd[ok]) ** 2))),
            "probes": sum(1 for e in probes if e.axis == a),
            "applied": sum(1 for r in mine if r.applied),
            "refused": {k: sum(1 for r in mine if r.reason == k)
                        for k in sorted({r.reason for r in mine if r.reason and not r.applied})},
            "final_bias_um": (int(exp[-1].bias_nm[-1, a]) / 1000.0
                              if exp and exp[-1].bias_nm is not None
                              and exp[-1].bias_nm.size else 0.0),
        }
    report.service = svc
