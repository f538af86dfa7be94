"""A power cut with the backup SRAM kept on a battery (VBAT): RESUME <periods off> continues the
box's state (docs/firmware.md, "Never worse than no compensation"; issue 41's "power cut"
event). Native firmware against the host's twin, which runs the periods off as samples with
every channel open."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from firmware_support import prepare_start_referenced

from thermal_comp.hil import replay as hil_replay
from thermal_comp.hil.checks import Judging, step_limits_nm
from thermal_comp.hil.expect import NO_REF, REFERENCED, WDT_RESET
from thermal_comp.hil.runner import Restart, Resume

CUT, OFF = 500, 5

pytestmark = pytest.mark.skipif(
    shutil.which("gcc") is None or shutil.which("make") is None,
    reason="gcc/make not installed: the native firmware cannot be built")


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    return prepare_start_referenced(tmp_path_factory.mktemp("hil_resume"),
                                    Judging(require_no_worse=False))


def test_a_resumed_box_goes_on_from_its_kept_state_bit_exact(setup):
    report, capture = hil_replay.run(setup, [Restart(CUT, battery=True, off=OFF),
                                             Resume(CUT + OFF, OFF)])
    assert report.ok, report.problems  # every line = the twin's, the periods off included
    after = capture.sessions[1]
    assert after.resumed and after.resume_acks[0].startswith(b"$OK,RESUME,")
    st = report.fw_status
    assert np.all(st[CUT + OFF:] & WDT_RESET) and np.all(st[CUT + OFF:] & REFERENCED)
    assert not np.any(st[CUT + OFF:] & NO_REF)  # its reference goes on: no ZERO needed
    # the rule of issue 41: no output beyond one step limit of the uninterrupted box's
    clean, _ = hil_replay.run(setup)
    limits = np.array([step_limits_nm(setup.model)[a] for a in setup.feed.axes])
    worst = np.abs(report.fw_out_nm[CUT + OFF:] - clean.fw_out_nm[CUT + OFF:]).max(axis=0)
    assert np.all(worst <= limits), (worst, limits)


def test_without_a_battery_there_is_nothing_to_resume(setup):
    report, capture = hil_replay.run(setup, [Restart(CUT, off=OFF), Resume(CUT + OFF, OFF)])
    after = capture.sessions[1]
    assert not after.resumed and after.resume_acks[0].startswith(b"$E,NO_STATE")
    assert np.all(report.fw_status[CUT + OFF:] & NO_REF)  # holds until a ZERO


def test_the_controllers_copy_of_the_state_stands_in_for_a_battery(setup):
    """No battery, but the controller asked SNAP after the last sample and gives the block back
    with LOAD after the boot: RESUME continues it line for line as on a battery."""
    report, capture = hil_replay.run(setup, [Restart(CUT, off=OFF, kept=True),
                                             Resume(CUT + OFF, OFF)])
    assert report.ok, report.problems
    after = capture.sessions[1]
    assert after.resumed and after.resume_acks[0].startswith(b"$OK,RESUME,")
    battery, _ = hil_replay.run(setup, [Restart(CUT, battery=True, off=OFF),
                                        Resume(CUT + OFF, OFF)])
    assert np.array_equal(report.fw_out_nm, battery.fw_out_nm)
    assert np.array_equal(report.fw_status, battery.fw_status)


def test_a_block_that_is_not_intact_is_not_continued(setup, monkeypatch):
    """One byte of the uploaded block changed: RESUME refuses it (CRC-32) and the box waits for
    a datum, as without any copy."""
    from thermal_comp.contract import protocol

    real = protocol.encode_load
    monkeypatch.setattr(protocol, "encode_load",
                        lambda block: real(block[:100] + bytes([block[100] ^ 1]) + block[101:]))
    report, capture = hil_replay.run(setup, [Restart(CUT, off=OFF, kept=True),
                                             Resume(CUT + OFF, OFF)])
    after = capture.sessions[1]
    assert not after.resumed and after.resume_acks[0].startswith(b"$E,NO_STATE")
    assert np.all(report.fw_status[CUT + OFF:] & NO_REF)


def _sample_lines_from(capture, first: int) -> list[bytes]:
    lines = [ln for s in capture.sessions for ln in s.lines if ln.startswith(b"$C,")]
    return [ln for ln in lines if int(ln.split(b",")[1]) >= first]


def test_a_watchdog_reset_before_resume_does_not_continue_the_held_block(setup):
    """Battery cut, then a watchdog reset before the controller's RESUME: the block kept for
    RESUME is marked held, so the warm boot does not continue it as if the box had never been
    off (before the mark: 1.5 um off on dx at once); RESUME then gives the battery case's lines
    byte for byte."""
    _, battery = hil_replay.run(setup, [Restart(CUT, battery=True, off=OFF),
                                        Resume(CUT + OFF, OFF)])
    _, capture = hil_replay.run(setup, [Restart(CUT, battery=True, off=OFF),
                                        Restart(CUT + OFF, wdt_reset=True),
                                        Resume(CUT + OFF, OFF)])
    assert capture.sessions[2].resumed
    want = _sample_lines_from(battery, CUT + OFF)
    assert len(want) > 100 and _sample_lines_from(capture, CUT + OFF) == want
