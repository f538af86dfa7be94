"""HIL on the emulated STM32F405: the cross-compiled image under qemu-system-arm (netduinoplus2),
samples fed over USART2 (board variant qemu_uartfeed), judged by the same runner on USART1.

Its sample lines must equal the native build's byte for byte and the host expectation bit for
bit. Kept short (the first 800 samples of the real run, with an open thermocouple in the
middle, about 2 s of emulation); `python -m thermal_comp.hil replay --target qemu` does whole runs.
"""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest
from firmware_support import prepare_fl_head

from thermal_comp.hil import replay as hil_replay
from thermal_comp.hil.capture_compare import capture_differences, sample_lines
from thermal_comp.hil.expect import HOLD, OPEN
from thermal_comp.hil.runner import ChipFault

N = 800

pytestmark = [
    pytest.mark.skipif(shutil.which("qemu-system-arm") is None,
                       reason="qemu-system-arm not installed (apt-get install "
                       "--no-install-recommends qemu-system-arm)"),
    pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None,
                       reason="arm-none-eabi-gcc not installed: no STM32F405 image to emulate"),
    pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed"),
]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    return prepare_fl_head(tmp_path_factory.mktemp("hil_qemu"), N)


def test_qemu_image_matches_native_build_and_twin(setup):
    from thermal_comp.hil import qemu

    events = [ChipFault(300, 2, 0x01), ChipFault(340, 2, 0x00)]  # T04 open for 40 samples
    # this test is about QEMU = native = twin; the accuracy verdict on an 800-sample head of FL
    # (worse than raw on it) is the accuracy bench's business, not this one's
    setup.judging = replace(setup.judging, require_no_worse=False)
    report, capture = hil_replay.run(setup, events, start_box=qemu.box_factory(setup))
    assert report.ok, report.problems
    assert report.received == N and capture.sessions[0].exit_code == 0
    assert b",OK," in capture.sessions[0].info
    assert np.all(report.fw_status[300:340] & (OPEN | HOLD) == OPEN | HOLD)
    _, native = hil_replay.run(setup, events)
    assert capture_differences(capture, native) == (0, "")
    assert len(sample_lines(capture)) == N


def test_every_command_is_answered_while_the_box_sleeps(setup):
    """Idle between samples, the image sleeps in WFI with no SysTick. A command whose last byte
    lands after the main loop read USART1 but before the core masked interrupts used to leave
    it asleep with the command queued, so the host waited for good (once in CI; within about
    150 back-to-back INFOs before the fix). 2,000 in a row must each be answered."""
    from thermal_comp.hil import qemu

    box = qemu.box_factory(setup)(False)
    try:
        for i in range(2000):
            reply = box.link.command("INFO", b"$I,", timeout=5.0)
            assert b",OK," in reply, (i, reply)
    finally:
        box.kill()
