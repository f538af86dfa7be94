"""The STM32F405 image: size budget, integer-only, boots in QEMU (netduinoplus2) and speaks the
protocol on USART1; `make flash` without a probe fails with one clear sentence."""

from __future__ import annotations

import shutil
import socket
import subprocess
import time

import pytest
from firmware_support import FIRMWARE, build, load_generator

from thermal_comp.contract import protocol as p

gen = load_generator()
ARM = shutil.which("arm-none-eabi-gcc")
QEMU = shutil.which("qemu-system-arm")
pytestmark = pytest.mark.skipif(ARM is None, reason="needs arm-none-eabi-gcc")

FLASH_BUDGET = 16 * 1024
RAM_BUDGET = 4 * 1024


@pytest.fixture(scope="module")
def image(tmp_path_factory):
    from thermal_comp import codegen

    tmp = tmp_path_factory.mktemp("stm32")
    header = codegen.generate(gen.test_model(period=0.25))  # 4 samples/s: a short QEMU run
    (tmp / "model.h").write_text(header.text)
    proc = build(tmp / "model.h", tmp / "stm32", board="stm32f405")
    return {"dir": tmp / "stm32", "header": header, "stdout": proc.stdout, "tmp": tmp}


def test_build_prints_size_and_fits_the_budget_for_8_channels_3_axes(image):
    out = image["stdout"]
    assert "text" in out and "bss" in out  # arm-none-eabi-size ran
    text, data, bss = (int(v) for v in out.splitlines()[-1].split()[:3])
    assert text + data < FLASH_BUDGET
    assert data + bss < RAM_BUDGET  # bss includes the 1 KiB stack
    for suffix in ("elf", "bin", "hex"):
        assert (image["dir"] / f"thermal_box.{suffix}").stat().st_size > 0


def test_image_has_no_floating_point_code(image):
    syms = subprocess.run(["arm-none-eabi-nm", str(image["dir"] / "thermal_box.elf")],
                          capture_output=True, text=True, check=True).stdout
    assert "Reset_Handler" in syms and "tcm_step" in syms
    assert not [s for s in syms.split() if s.startswith(("__aeabi_f", "__aeabi_d"))]


def test_image_links_no_64_bit_division_helper(image):
    # __udivmoddi4 and its wrappers are 0.9 KiB: the catch-up and the estimator's gain divide
    # in 32 bits or by shifts (firmware/src/model_eval.c, estimator.c)
    syms = subprocess.run(["arm-none-eabi-nm", str(image["dir"] / "thermal_box.elf")],
                          capture_output=True, text=True, check=True).stdout.split()
    assert not [s for s in syms if s in ("__aeabi_ldivmod", "__aeabi_uldivmod", "__udivmoddi4",
                                         "__divdi3", "__udivdi3", "__moddi3", "__umoddi3")]


def test_flash_without_probe_says_so_in_one_sentence(image):
    if shutil.which("openocd") is None:
        pytest.skip("needs openocd")
    r = subprocess.run(["make", "-s", "-C", str(FIRMWARE), "flash",
                        f"MODEL={image['tmp'] / 'model.h'}", f"BUILD={image['dir']}"],
                       capture_output=True, text=True, timeout=120)
    if r.returncode == 0:
        pytest.skip("an ST-LINK probe is attached: the box was flashed")
    ours = [line for line in r.stderr.splitlines() if line.startswith("make flash:")]
    assert len(ours) == 1
    assert "no ST-LINK probe was found" in ours[0] and "make hil" in ours[0]


@pytest.mark.skipif(QEMU is None, reason="needs qemu-system-arm")
def test_image_boots_in_qemu_and_answers_on_usart1(image):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    qemu = subprocess.Popen(
        [QEMU, "-M", "netduinoplus2", "-nographic", "-monitor", "none",
         "-kernel", str(image["dir"] / "thermal_box.elf"),
         "-chardev", f"socket,id=u1,host=127.0.0.1,port={port},server=on,wait=on,nodelay=on",
         "-serial", "chardev:u1"],
        stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 20
        while True:
            try:
                conn = socket.create_connection(("127.0.0.1", port), timeout=1)
                break
            except OSError:
                if time.monotonic() > deadline or qemu.poll() is not None:
                    raise
                time.sleep(0.05)
        # `wait=on`: QEMU starts the machine only once the serial port is connected.
        conn.settimeout(10)
        reader = conn.makefile("rb")
        time.sleep(0.2)  # let the firmware enable USART1 (earlier bytes are dropped)
        conn.sendall(b"INFO\r\n")
        lines = []
        while len([m for m in lines if isinstance(m, p.Sample)]) < 2:
            lines.append(p.decode(reader.readline()))
        info = next(m for m in lines if isinstance(m, p.Info))
        assert info.crc_ok and info.model_hash == image["header"].model.model_hash
        assert info.period_ms == 250
        samples = [m for m in lines if isinstance(m, p.Sample)]
        # QEMU's SPI1 has nothing attached (reads 0): every chip is "not responding", so the
        # box holds with no data, exactly as it would with the sensor cable unplugged.
        assert samples[0].seq == 0 and samples[1].seq == 1
        assert samples[0].flags & p.Status.TC_FAULT and samples[0].flags & p.Status.NO_DATA
        conn.sendall(b"STATUS\r\n")
        status = p.decode(reader.readline())
        while not isinstance(status, p.StatusReport):
            status = p.decode(reader.readline())
        assert status.channel_faults == (p.ChannelFault.NO_RESPONSE,) * 8
        conn.close()
    finally:
        qemu.kill()
        qemu.wait()
