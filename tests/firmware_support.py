"""Helpers for the firmware tests: build the firmware against a codegen header, run the native
board (docs/native-board.md) and talk to it over its pty.

The test model and its host-side expectations live in firmware/test/gen_test_model.py (also
used by `make -C firmware test`), loaded here by path.
"""

from __future__ import annotations

import importlib.util
import os
import re
import select
import subprocess
import sys
import termios
import tty
from pathlib import Path

import serial

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware"


def load_generator():
    """firmware/test/gen_test_model.py as a module."""
    path = FIRMWARE / "test" / "gen_test_model.py"
    spec = importlib.util.spec_from_file_location("gen_test_model", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def build(header: Path, out_dir: Path, board: str = "native", sanitize: bool = True,
          cflags: str = "") -> subprocess.CompletedProcess:
    """make -C firmware for ``board`` into ``out_dir``; raises with the compiler's output."""
    cmd = ["make", "-s", "-C", str(FIRMWARE), f"BOARD={board}", f"MODEL={header}",
           f"BUILD={out_dir}", f"SANITIZE={1 if sanitize else 0}", f"BOX_CFLAGS={cflags}"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stdout}{proc.stderr}")
    return proc


# The box before issue 42's MEAS (the in-service estimator): bench firmware reports the growth
# since then (MEAS and every later feature); MEAS's own share is held to the 1 KiB /
# 256 B (docs/service.md, "Flash and RAM").
MEAS_BASELINE = "091baec"
MEAS_FLASH_BUDGET = 1024
MEAS_RAM_BUDGET = 256


def stm32_sizes(stdout: str) -> tuple[int, int]:
    """(flash = text + data, RAM = data + bss) from arm-none-eabi-size's last line."""
    text, data, bss = (int(v) for v in stdout.splitlines()[-1].split()[:3])
    return text + data, data + bss


def baseline_stm32_sizes(tmp: Path, period: float | None = None,
                         commit: str = MEAS_BASELINE) -> tuple[int, int] | None:
    """(flash, RAM) of the STM32F405 image at ``commit`` for the same test model, written by
    that commit's own generator and codegen (its runtime format); None without the commit
    (no git, a shallow clone or an exported tree)."""
    src = tmp / f"baseline-{commit}"
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", commit, "firmware", "codegen",
                              "contract"], capture_output=True)
    if archive.returncode != 0:
        return None
    src.mkdir(parents=True)
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive.stdout, check=True)
    kwargs = "" if period is None else f"period={period!r}"
    script = ("import importlib.util, sys\n"
              f"sys.path[:0] = [{str(src)!r}]\n"
              "spec = importlib.util.spec_from_file_location('g', sys.argv[1])\n"
              "g = importlib.util.module_from_spec(spec); spec.loader.exec_module(g)\n"
              "import codegen\n"
              f"open(sys.argv[2], 'w').write(codegen.generate(g.test_model({kwargs})).text)\n")
    header = src / "model.h"
    subprocess.run([sys.executable, "-I", "-c", script,
                    str(src / "firmware" / "test" / "gen_test_model.py"), str(header)],
                   check=True, capture_output=True)
    cmd = ["make", "-s", "-C", str(src / "firmware"), "BOARD=stm32f405", f"MODEL={header}",
           f"BUILD={src / 'stm32'}"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stdout}{proc.stderr}")
    return stm32_sizes(proc.stdout)


def private_pty() -> tuple[int, int]:
    """(master, slave) of a fresh raw pty: the master goes to the firmware (--pty-fd), the
    slave stays ours and is opened by descriptor, never by a /dev/pts path another process
    could have been given (docs/hil.md)."""
    master, slave = os.openpty()
    tty.setraw(slave, termios.TCSANOW)
    return master, slave


class Box:
    """One native firmware process: ``feed`` writes stdin, ``lines`` reads the pty."""

    def __init__(self, binary: Path, *args: str, keep_master: bool = False) -> None:
        """``keep_master``: hold a copy of the pty's master so that lines the board wrote just
        before it exits are still read (a last master closing hangs the pty up, and Linux then
        drops what the reader had not read yet); a dead board then shows as silence, not EIO."""
        master, self._slave = private_pty()
        self._master = -1
        try:
            self.proc = subprocess.Popen([str(binary), "--pty-fd", str(master), *args],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         stderr=subprocess.PIPE, bufsize=0, pass_fds=(master,))
        finally:
            if keep_master:
                self._master = master
            else:
                os.close(master)
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], 30.0)
        first = self.proc.stdout.readline().decode() if ready else ""
        if not first.startswith("PTY "):
            self.proc.kill()
            raise RuntimeError(f"no 'PTY <path>' line, got {first!r}")
        self.port = serial.Serial(f"/proc/self/fd/{self._slave}", 115200, timeout=20.0)

    def feed(self, text: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(text.encode())

    def send(self, raw: bytes) -> None:
        self.port.write(raw)

    def lines(self, n: int) -> list[bytes]:
        """The next n lines from the box (with their CRLF); fails after 20 s of silence."""
        out = []
        for _ in range(n):
            line = self.port.readline()
            if not line.endswith(b"\n"):
                raise AssertionError(f"box sent {len(out)} of {n} lines, then {line!r}")
            out.append(line)
        return out

    def silent(self, seconds: float = 0.3) -> bool:
        """True if nothing arrives on the pty within ``seconds``."""
        self.port.timeout = seconds
        data = self.port.read(1)
        self.port.timeout = 20.0
        return data == b""

    def finish(self, timeout: float = 10.0) -> tuple[int, str]:
        """Send Q (if stdin is open), wait; returns (exit status, stderr)."""
        try:
            self.feed("Q\n")
        except (BrokenPipeError, OSError, ValueError):  # the feed may be closed already
            pass
        try:
            rc = self.proc.wait(timeout)
        finally:
            self.port.close()
            if self._slave >= 0:
                os.close(self._slave)
                self._slave = -1
            if self._master >= 0:
                os.close(self._master)
                self._master = -1
            if self.proc.poll() is None:
                self.proc.kill()
        assert self.proc.stderr is not None
        return rc, self.proc.stderr.read().decode()

    def close_feed(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()



def box_defaults() -> dict[str, int]:
    """The build-time defaults of firmware/include/box_config.h (BOX_* integer macros)."""
    text = (FIRMWARE / "include" / "box_config.h").read_text()
    return {m.group(1): int(m.group(2))
            for m in re.finditer(r"^#define (BOX_[A-Z0-9_]+) (-?\d+)$", text, re.M)}


def prepare_fl_head(d: Path, n: int, cflags: str = ""):
    """The first ``n`` samples of the real FL run and the HIL's FL model, ready to replay
    (hil.replay.prepare) from the build directory ``d/hil``."""
    from thermal_comp.hil import replay as hil_replay
    from thermal_comp.hil.example_model import fl_thermal_model, write_model
    from thermal_comp.host.io import load_run, write_run

    fl = ROOT / "examples" / "fl_thermal_steps.csv"
    run = load_run(fl, targets=["ch1_um", "ch3_um"], sensors="T*", aux=["spindle_rpm"])
    cols = {k: v[:n] for k, v in run.columns().items() if k != "time_s"}
    write_run(d / "fl_head.csv", run.time_s[:n], cols, precision=9)
    model = write_model(fl_thermal_model(fl), d / "model.json")
    return hil_replay.prepare(model, d / "fl_head.csv", d / "hil", cflags=cflags)


def prepare_start_referenced(d: Path, judging=None):
    """A start-referenced model (what ``host train`` gives by default: the box zeroes at the
    job's ZERO, boots NO_REF after a power cut) with the trained windows host train writes,
    fitted on examples/sim_step.csv, ready to replay sim_random (which it never saw)."""
    from dataclasses import replace

    from thermal_comp.hil import replay as hil_replay
    from thermal_comp.hil.example_model import default_terms, fit_example_model, write_model
    from thermal_comp.host.io import load_run

    step = ROOT / "examples" / "sim_step.csv"
    terms = {"dx_um": default_terms(["T03", "T04", "T01"], 60.0, "spindle_rpm"),
             "dz_um": default_terms(["T05", "T01", "T02"], 60.0, "spindle_rpm")}
    model = fit_example_model(step, terms, aux_names=["spindle_rpm"])
    model["reference"] = {"kind": "start", "samples": 1}
    run = load_run(step, [], [c["sensor"] for c in model["channels"]], [])
    for c, t in zip(model["channels"], run.temperatures.T, strict=True):
        c["trained_min_c"], c["trained_max_c"] = float(t.min()), float(t.max())
    s = hil_replay.prepare(write_model(model, d / "model.json"),
                           ROOT / "examples" / "sim_random.csv", d / "hil")
    assert s.build.zero_at_powerup
    return s if judging is None else replace(s, judging=judging)
