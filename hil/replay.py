"""One HIL replay end to end: header → firmware → feed → box → expectation → report.

This is the library behind ``python -m hil replay`` and the fault-scenario tests. Everything
the report calls "expected" comes from the host (the twin and the documented output stage);
the firmware only ever supplies the lines being judged.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from codegen.fixed import FixedModel
from contract.fixed_point import CODE_MAX, CODE_MIN
from hil.build import ModelBuild, build_firmware, prepare_header
from hil.checks import Judging, ReplayReport, judge
from hil.expect import Expected, OutputConfig, expect_session, sr_timeline
from hil.feed import Feed, build_feed
from hil.native import NativeBox
from hil.runner import Box, Capture, ChipFault, Event, Zero, replay
from host.fitting import Reference


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
    feed = build_feed(mb.model, data, reference)
    return ReplaySetup(mb, feed, FixedModel(q), exe, output)


def expectations(setup: ReplaySetup, capture: Capture, events: Sequence[Event],
                 model_bad: bool = False) -> list[Expected]:
    """The host's expectation for every session of a capture."""
    codes = np.clip(np.asarray(capture.codes_fed, dtype=np.int64), CODE_MIN, CODE_MAX)
    codes = codes.reshape(capture.n_samples, setup.feed.codes.shape[1])
    faults = [(e.at, e.channel, e.sr) for e in events if isinstance(e, ChipFault)]
    sr = sr_timeline(capture.n_samples, codes.shape[1], faults)
    zeros = [e.at for e in events if isinstance(e, Zero)]
    out = []
    for s in capture.sessions:
        rows = slice(s.first_sample, s.first_sample + s.n_fed)
        local = [z - s.first_sample for z in zeros
                 if s.first_sample <= z < s.first_sample + s.n_fed]
        out.append(expect_session(setup.twin, codes[rows], setup.feed.aux[rows], sr[rows],
                                  setup.output, wdt_reset=s.wdt_reset, model_bad=model_bad,
                                  zero_before=local,
                                  zero_at_powerup=setup.build.zero_at_powerup))
    return out


def run(setup: ReplaySetup, events: Sequence[Event] = (), model_bad: bool = False,
        quiet: bool = True, window: int = 256,
        start_box: Callable[[bool], Box] | None = None) -> tuple[ReplayReport, Capture]:
    """Replay the setup's run through the firmware and judge it."""
    def native(wdt: bool) -> Box:
        return NativeBox(setup.binary, wdt_reset=wdt)

    t0 = time.perf_counter()
    capture = replay(setup.feed, start_box or native, events, window=window, quiet=quiet)
    elapsed = time.perf_counter() - t0
    # a deliberately corrupted model is expected to correct nothing
    judging = replace(setup.judging, require_correction=False) if model_bad else setup.judging
    report = judge(capture, expectations(setup, capture, events, model_bad), setup.feed,
                   setup.model, setup.bounds_um(), judging,
                   [e.at for e in events if isinstance(e, Zero)],
                   box_zeroes=setup.build.zero_at_powerup)
    report.elapsed_s = elapsed
    return report, capture
