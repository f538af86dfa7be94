"""`host monitor` over pseudo-terminals: noise on the wire, a lost and re-plugged port, the model
hash check, and the CSV log, with every expected value computed here from the bytes sent."""

from __future__ import annotations

import binascii
import csv
import io
import json
import os
import select
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from thermal_comp.host.box import Monitor, render
from thermal_comp.host.cli import main as host_main


def wire(payload: str) -> bytes:
    """One protocol line, CRC-16/CCITT-FALSE computed here with binascii."""
    body = payload.encode("ascii")
    return b"$" + body + b"*%04X\r\n" % binascii.crc_hqx(body, 0xFFFF)


INFO = wire("I,fw-1.2.3,0123456789abcdef,OK,1000,dx_um;dz_um,0:T05:K;1:T12:K")


def sample(seq: int, status: int, corr_nm: list[int], codes: list[int]) -> bytes:
    return wire(f"C,{seq},{status:04X},{len(corr_nm)},"
                + "".join(f"{c}," for c in corr_nm) + f"{len(codes)}"
                + "".join(f",{c}" for c in codes))


class WirePty:
    """A pty whose far end the test drives byte by byte, to inject line noise and unplugging
    that the real firmware never produces on demand."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        self.path = os.ttyname(slave)
        self._slave = slave  # kept open so the device exists until the monitor opens it
        self.received = b""

    def wait_for(self, needle: bytes, timeout: float = 5.0) -> None:
        deadline = time.monotonic() + timeout
        while needle not in self.received:
            left = deadline - time.monotonic()
            assert left > 0, f"monitor never sent {needle!r} (got {self.received!r})"
            ready, _, _ = select.select([self.master], [], [], left)
            if ready:
                self.received += os.read(self.master, 1024)

    def send(self, data: bytes) -> None:
        os.write(self.master, data)

    def unplug(self) -> None:
        os.close(self._slave)
        os.close(self.master)


def run_in_thread(monitor: Monitor) -> tuple[threading.Thread, dict]:
    result: dict = {}

    def target() -> None:
        result["code"] = monitor.run()

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    return thread, result


def test_noise_is_counted_and_samples_are_logged(tmp_path):
    box = WirePty()
    log = tmp_path / "live.csv"
    out = io.StringIO()
    monitor = Monitor(box.path, count=4, log=log, out=out, screen=False,
                      expected_hash="0123456789abcdef")
    thread, result = run_in_thread(monitor)
    box.wait_for(b"INFO\r\n")
    box.send(INFO)
    good = [(0, 0x0000, [1234, -5678], [3200, 3328]),
            (1, 0x0002, [1300, -5600], [3201, 3330]),
            (3, 0x0220, [1400, -5500], [3202, -12]),   # seq 2 lost; OPEN + NO_DATA flags
            (4, 0x0000, [-1, 0], [3203, 3333])]
    corrupted = bytearray(sample(2, 0, [1, 2], [3, 4]))
    corrupted[5] ^= 0x01  # one flipped bit in the payload: the CRC must catch it
    box.send(sample(*good[0]) + b"hello\r\n" + bytes(corrupted) + sample(*good[1])
             + b"\x00\xff\xfe junk\n" + sample(*good[2]) + b"$C,5,0000*ZZZZ\r\n"
             + sample(*good[3]))
    thread.join(10)
    assert not thread.is_alive()
    assert result["code"] == 0
    state = monitor.state
    assert (state.samples, state.bad_lines, state.seq_gaps) == (4, 4, 1)
    assert state.info is not None and state.hash_ok is True

    with log.open(newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["time_s", "seq", "status", "corr_dx_um", "corr_dz_um", "T05", "T12",
                       "faults", "host_unix_s"]
    for row, (seq, status, corr, codes) in zip(rows[1:], good, strict=True):
        assert float(row[0]) == seq * 1.0 and int(row[1]) == seq
        assert int(row[2], 16) == status
        assert [float(v) for v in row[3:5]] == [c / 1000 for c in corr]
        if status & 0x0020:
            # OPEN, and the box was never asked which channel (STATUS unanswered): neither
            # reading is a temperature, both cells are empty and the faults column says why
            assert row[5:8] == ["", "", "T05=OPEN?;T12=OPEN?"]
        else:
            assert [float(v) for v in row[5:7]] == pytest.approx([c / 128 for c in codes],
                                                                 abs=1e-4)
            assert row[7] == ""

    text = out.getvalue()
    assert "\x1b[" not in text  # plain mode: no escape sequences in a pipe
    assert "status=0220[OPEN,NO_DATA]" in text
    assert "dx_um=+1.234um" in text and "T12=FAULT(OPEN?)" in text and "-0.09C" not in text
    assert text.count("bad line #") == 4
    # the fault history: each fault when it came and when it cleared
    assert "fault: HOLD since" in text and "at #1" in text
    assert "cleared: HOLD at" in text and "at #3" in text
    assert "cleared: OPEN at" in text and "at #4" in text
    box.unplug()


def test_existing_log_is_appended_and_a_different_layout_is_refused(tmp_path):
    log = tmp_path / "live.csv"
    for expected_rows in (2, 3):
        box = WirePty()
        monitor = Monitor(box.path, count=1, log=log, out=io.StringIO(), screen=False)
        thread, result = run_in_thread(monitor)
        box.wait_for(b"INFO\r\n")
        box.send(INFO + sample(expected_rows, 0, [1, 2], [3, 4]))
        thread.join(10)
        assert result["code"] == 0
        assert len(log.read_text().splitlines()) == expected_rows  # one header only
        box.unplug()

    box = WirePty()
    other = wire("I,fw-1.2.3,0123456789abcdef,OK,1000,dy_um,0:T05:K")
    monitor = Monitor(box.path, count=1, log=log, out=io.StringIO(), screen=False)
    errors: list[BaseException] = []

    def target() -> None:
        try:
            monitor.run()
        except ValueError as exc:
            errors.append(exc)

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    box.wait_for(b"INFO\r\n")
    box.send(other + sample(9, 0, [5], [6]))
    thread.join(10)
    assert errors and "existing log has columns" in str(errors[0])
    assert len(log.read_text().splitlines()) == 3  # nothing appended
    box.unplug()


def test_lost_port_is_retried_and_the_box_asked_again(tmp_path):
    link = tmp_path / "ttyBOX"  # like /dev/serial/by-id/...: a stable name for a changing device
    first = WirePty()
    link.symlink_to(first.path)
    out = io.StringIO()
    monitor = Monitor(str(link), count=4, out=out, screen=False, retry_s=0.05,
                      expected_hash="0123456789abcdef")
    thread, result = run_in_thread(monitor)
    first.wait_for(b"INFO\r\n")
    first.send(INFO + sample(0, 0, [1, 2], [3, 4]) + sample(1, 0, [1, 2], [3, 4]))
    deadline = time.monotonic() + 5
    while monitor.state.samples < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    first.unplug()
    time.sleep(0.3)  # the monitor notices and keeps retrying a missing device
    assert thread.is_alive()
    second = WirePty()
    link.unlink()
    link.symlink_to(second.path)
    second.wait_for(b"INFO\r\n", timeout=20.0)  # asked again after reconnecting
    second.send(INFO + sample(0, 0x0100, [5, 6], [7, 8]) + sample(1, 0, [5, 6], [7, 8]))
    thread.join(10)
    assert not thread.is_alive() and result["code"] == 0
    assert monitor.state.samples == 4 and monitor.state.reconnects == 1
    assert monitor.state.bad_lines == 0
    assert "connection lost" in out.getvalue()
    second.unplug()


def test_hash_mismatch_is_shown_and_fails_the_run():
    box = WirePty()
    out = io.StringIO()
    monitor = Monitor(box.path, count=1, out=out, screen=False, expected_hash="ffffffffffffffff")
    thread, result = run_in_thread(monitor)
    box.wait_for(b"INFO\r\n")
    box.send(INFO + sample(0, 0, [1, 2], [3, 4]))
    thread.join(10)
    assert result["code"] == 1
    assert "MISMATCH: model.json is ffffffffffffffff" in out.getvalue()
    box.unplug()


def test_the_screen_shows_the_state_render_gives():
    box = WirePty()
    out = io.StringIO()
    monitor = Monitor(box.path, count=2, out=out, screen=False)
    thread, result = run_in_thread(monitor)
    box.wait_for(b"INFO\r\n")
    box.send(INFO + sample(7, 0x0008, [-250, 99999], [3200, 3456]) + b"garbage\r\n")
    time.sleep(0.3)
    box.send(sample(8, 0x0008, [-250, 99999], [3200, 3456]))
    thread.join(10)
    assert result["code"] == 0
    screen = render(monitor.state, time.monotonic())
    assert any("dx_um" in ln and "-0.250 µm" in ln for ln in screen)
    assert any("dz_um" in ln and "+99.999 µm" in ln for ln in screen)
    assert any("T05   25.00 °C" in ln and "T12   27.00 °C" in ln for ln in screen)
    assert any("CLAMP" in ln for ln in screen)
    assert any("bad lines 1" in ln for ln in screen)
    box.unplug()


def test_cli_reports_a_port_that_cannot_be_opened(tmp_path, capsys):
    code = host_main(["monitor", str(tmp_path / "no-such-tty"), "--count", "1"])
    assert code == 2
    assert "no-such-tty: cannot open serial port" in capsys.readouterr().err


def test_cli_counts_samples_from_a_pty(tmp_path, capsys):
    box = WirePty()
    result: dict = {}

    def target() -> None:
        result["code"] = host_main(["monitor", box.path, "--count", "2", "--log",
                                    str(tmp_path / "l.csv")])

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    box.wait_for(b"INFO\r\n")
    box.send(INFO + sample(0, 0, [1, 2], [3, 4]) + sample(1, 0, [1, 2], [3, 4]))
    thread.join(10)
    assert result["code"] == 0
    assert "monitor: 2 samples, 0 bad lines" in capsys.readouterr().out
    assert len(Path(tmp_path / "l.csv").read_text().splitlines()) == 3
    box.unplug()


# ---------------------------------------------------------------- the real native firmware

ROOT = Path(__file__).resolve().parents[3]
NATIVE_MODEL = {
    "schema": "thermal-model/1", "tool_version": "0.1.0", "sample_period_s": 1.0,
    # The tests step temperatures by up to 10 degC from one sample to the next on purpose:
    # the model allows it (max_step_c, max_step_um), so the box neither flags IMPLAUSIBLE nor
    # limits the output step (docs/firmware.md).
    "channels": [{"channel": 0, "sensor": "T05", "tc_type": "K", "min_c": -40.0, "max_c": 200.0,
                  "max_step_c": 50.0},
                 {"channel": 1, "sensor": "T12", "tc_type": "K", "min_c": -40.0, "max_c": 200.0,
                  "max_step_c": 50.0}],
    "aux": [], "time_max_s": 604800.0,
    "axes": {"dx_um": {"unit": "um", "intercept": -12.5, "max_step_um": 100.0,
                       "terms": [{"kind": "temp", "source": "T05", "coef": 0.75}],
                       "metrics": {"promise": "RMS on an unseen day ≤ 1.50 µm on 80 % of days"}},
             "dz_um": {"unit": "um", "intercept": 3.0, "max_step_um": 100.0,
                       "terms": [{"kind": "temp", "source": "T05", "coef": -1.25},
                                 {"kind": "temp", "source": "T12", "coef": 2.0}]}},
    "training": {"runs": [], "targets": ["dx_um", "dz_um"], "sensors": "T*"},
}


@pytest.fixture(scope="module")
def native_box(tmp_path_factory):
    """The native firmware built for a small model (cold-start slew off, so every sample's
    correction is the model's value) in a private build directory."""
    return _build_native(tmp_path_factory.mktemp("native_monitor"), NATIVE_MODEL)


def _build_native(tmp: Path, model: dict) -> tuple[Path, Path]:
    if shutil.which("gcc") is None or shutil.which("make") is None:
        pytest.skip("gcc/make not installed: cannot build the native firmware")
    from thermal_comp.codegen import write_header

    model_path = tmp / "model.json"
    model_path.write_text(json.dumps(model))
    write_header(model_path, tmp / "model.h")
    build = subprocess.run(["make", "-s", "-C", str(ROOT / "firmware"), "BOARD=native",
                            f"MODEL={tmp / 'model.h'}", f"BUILD={tmp / 'fw'}",
                            "BOX_CFLAGS=-DBOX_COLD_START_SLEW=0"],
                           capture_output=True, text=True)
    assert build.returncode == 0, build.stdout + build.stderr
    return tmp / "fw" / "thermal_box", model_path


def start_native(binary: Path):
    proc = subprocess.Popen([str(binary)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, bufsize=0)
    assert proc.stdout is not None
    line = proc.stdout.readline().decode().strip()
    assert line.startswith("PTY "), line
    return proc, line[4:]

def _monitor_native(binary: Path, model_path: Path, temps: list[tuple[float, float]],
                    extra: list[str] | None = None) -> tuple[int, str, str, str]:
    """Start the native box and `host monitor --model` on its pty, feed (T05, T12) samples,
    and return the monitor's (exit code, first line, rest of stdout, stderr)."""
    box, pty = start_native(binary)
    monitor = subprocess.Popen([sys.executable, "-m", "thermal_comp.host", "monitor", pty,
                                "--model",
                                str(model_path), "--count", str(len(temps)), *(extra or [])],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               cwd=ROOT)
    try:
        assert monitor.stdout is not None and box.stdin is not None
        first = monitor.stdout.readline()
        assert first.startswith("connected to"), first + (monitor.stderr.read() or "")
        feed = "".join(f"S 0 {round(a * 128)} {round(b * 128)}\n" for a, b in temps)
        box.stdin.write(feed.encode())
        box.stdin.flush()
        # not communicate(): it reads the pipe's descriptor and would lose whatever readline()
        # above already buffered (the INFO line often arrives with "connected to"). The output
        # is a few lines, far below a pipe's capacity, so waiting first cannot deadlock.
        monitor.wait(timeout=30)
        out, err = monitor.stdout.read(), monitor.stderr.read() if monitor.stderr else ""
    finally:
        if monitor.poll() is None:
            monitor.kill()
        box.stdin.write(b"Q\n")
        box.stdin.close()
        box.wait(10)
    return monitor.returncode, first, out, err


def test_monitor_on_the_native_firmware_over_its_pty(native_box, tmp_path):
    binary, model_path = native_box
    log = tmp_path / "native.csv"
    # the monitor has the port open (pyserial flushes input on open): feed six samples
    temps = [(25.0, 22.0), (25.5, 22.25), (26.0, 22.5), (27.25, 23.0), (28.0, 23.5),
             (30.0, 24.0)]
    code, first, out, err = _monitor_native(binary, model_path, temps, ["--log", str(log)])
    assert code == 0, first + out + err
    assert "matches model.json" in out
    with log.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 6
    for row, (t05, t12) in zip(rows, temps, strict=True):
        dx = -12.5 + 0.75 * t05  # the float model, written out here
        dz = 3.0 - 1.25 * t05 + 2.0 * t12
        assert float(row["corr_dx_um"]) == pytest.approx(dx, abs=0.0015)
        assert float(row["corr_dz_um"]) == pytest.approx(dz, abs=0.0015)
        assert (float(row["T05"]), float(row["T12"])) == (t05, t12)
        assert int(row["status"], 16) == 0
    assert [int(r["seq"]) for r in rows] == list(range(int(rows[0]["seq"]),
                                                       int(rows[0]["seq"]) + 6))


def test_monitor_names_the_channels_behind_extrap(tmp_path):
    """T05 trained over 20..30 degC: its window is 19.5..30.5 degC (docs/protocol.md, 5 % of the
    span). At 35 degC the box raises EXTRAP and the monitor says which channel; at 25 it does
    not. T12 has no training range, so it never counts."""
    model = json.loads(json.dumps(NATIVE_MODEL))
    model["channels"][0].update(trained_min_c=20.0, trained_max_c=30.0)
    binary, model_path = _build_native(tmp_path, model)
    _, _, out, _ = _monitor_native(binary, model_path, [(t05, 22.0) for t05 in (25.0, 35.0, 30.4)])
    samples = [line for line in out.splitlines() if line.startswith("seq=")]
    assert len(samples) == 3, out
    assert "EXTRAP" not in samples[0] and "EXTRAP" not in samples[2]  # 25 and 30.4 degC
    assert "EXTRAP(T05)" in samples[1] and "status=0400" in samples[1]  # 35 degC, bit 10


# ---------------------------------------------------------------- faults, staleness, identity

def status_line(status: int, seq: int, faults: list[int], zero: str | None = None) -> bytes:
    """A STATUS reply as docs/protocol.md writes it (with the trailing zero_seq if given)."""
    body = f"S,{status:04X},{seq},12," + ";".join(f"{w:04X}" for w in faults)
    return wire(body + ("" if zero is None else f",{zero}"))


def wait_until(cond, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "condition never met"
        time.sleep(0.01)


def test_a_faulted_channel_is_named_greyed_and_its_axes_hold():
    box = WirePty()
    out = io.StringIO()
    # dx reads T05 only, dz reads T05 and T12 (as the model's terms would say)
    monitor = Monitor(box.path, count=3, out=out, screen=False, expected_hash="0123456789abcdef",
                      axis_inputs={"dx_um": ["T05"], "dz_um": ["T05", "T12"]})
    thread, result = run_in_thread(monitor)
    box.wait_for(b"INFO\r\n")
    box.send(INFO + sample(0, 0, [1000, 2000], [3200, 3328]))
    wait_until(lambda: monitor.state.samples == 1)
    box.send(sample(1, 0x0022, [1000, 2000], [3200, 9999]))  # HOLD + OPEN: which ones?
    box.wait_for(b"STATUS\r\n")  # the monitor asks for the per-channel fault words
    box.send(status_line(0x0022, 1, [0x0000, 0x0001]))  # T12's MAX31856 SR: OPEN
    wait_until(lambda: monitor.state.status_report is not None)
    box.send(sample(2, 0x0022, [1000, 2000], [3201, 9999]))
    thread.join(10)
    assert result["code"] == 0
    last = [ln for ln in out.getvalue().splitlines() if ln.startswith("seq=")][-1]
    assert "status=0022[HOLD(dz_um),OPEN(T12)]" in last
    assert "T12=FAULT(OPEN)" in last and "T05=25.01C" in last
    assert "78.12" not in last  # 9999/128: the faulted channel's code is not a temperature
    screen = render(monitor.state, time.monotonic(), colour=True)
    grey = next(ln for ln in screen if "T12" in ln and "OPEN" in ln and "°C" in ln)
    assert "\x1b[90mT12" in grey  # greyed out on the terminal
    assert any("dz_um" in ln and "HOLD: last good value" in ln for ln in screen)
    assert not any("dx_um" in ln and "HOLD" in ln for ln in screen)
    box.unplug()


def test_silence_longer_than_two_periods_raises_stale():
    box = WirePty()
    out = io.StringIO()
    monitor = Monitor(box.path, duration=1.5, out=out, screen=False)
    thread, result = run_in_thread(monitor)
    box.wait_for(b"INFO\r\n")
    box.send(wire("I,fw-1,0123456789abcdef,OK,100,dx_um,0:T05:K") + wire("C,0,0000,1,5,1,3200"))
    time.sleep(0.5)  # 5 periods of 100 ms without a line
    assert monitor.state.stale
    box.send(wire("C,1,0000,1,6,1,3200"))
    thread.join(10)
    text = out.getvalue()
    assert "STALE: no sample for" in text and "expected every 0.1 s" in text
    assert "samples resumed after" in text
    assert text.index("STALE") < text.index("seq=1 ")
    box.unplug()


def test_sign_and_reference_are_stated_and_newer_bits_are_named():
    box = WirePty()
    out = io.StringIO()
    monitor = Monitor(box.path, count=2, out=out, screen=False)
    thread, result = run_in_thread(monitor)
    box.wait_for(b"INFO\r\n")
    box.send(INFO + sample(40, 0x0800, [-1500, 0], [3200, 3328]))  # bit 11: REFERENCED
    box.wait_for(b"STATUS\r\n")
    box.send(status_line(0x0800, 40, [0, 0]))  # an older STATUS reply (no zero_seq) is fine
    wait_until(lambda: monitor.state.status_report is not None)
    box.send(sample(41, 0x1800, [-1400, 0], [3200, 3328]))  # + bit 12: IMPLAUSIBLE
    thread.join(10)
    text = out.getvalue()
    assert "offset to apply is −correction" in text
    assert "status=0800[REFERENCED]" in text
    assert "status=1800[REFERENCED,IMPLAUSIBLE]" in text
    screen = render(monitor.state, time.monotonic())
    assert any("corrections are the change since ZERO" in ln for ln in screen)
    box.unplug()


def test_json_prints_one_object_per_line(capsys):
    box = WirePty()
    result: dict = {}

    def target() -> None:
        result["code"] = host_main(["monitor", box.path, "--count", "2", "--json"])

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    box.wait_for(b"INFO\r\n")
    box.send(INFO + sample(0, 0, [1234, -5], [3200, 3328]) + b"noise\r\n"
             + sample(1, 0x0400, [1235, -5], [3201, 3328]))
    thread.join(10)
    assert result["code"] == 0
    objects = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
    samples = [o for o in objects if o["type"] == "sample"]
    assert [s["seq"] for s in samples] == [0, 1]
    assert samples[0]["corrections_um"] == {"dx_um": 1.234, "dz_um": -0.005}
    assert samples[0]["temperatures_c"] == {"T05": 25.0, "T12": 26.0}
    assert samples[1]["flags"] == ["EXTRAP"] and samples[1]["status"] == "0400"
    assert any(o["type"] == "bad_line" for o in objects)
    assert any(o["type"] == "event" and o["event"] == "sign" for o in objects)
    assert objects[-1]["type"] == "summary" and objects[-1]["samples"] == 2
    box.unplug()


def test_after_a_reconnect_an_unidentified_device_shows_nothing_until_its_info(tmp_path):
    link = tmp_path / "ttyBOX"
    first = WirePty()
    link.symlink_to(first.path)
    out = io.StringIO()
    # it stops at the second sample it shows; the duration only bounds a broken run (a fixed
    # 4 s window was too short when the machine was loaded)
    monitor = Monitor(str(link), count=2, duration=30.0, out=out, screen=False, retry_s=0.05,
                      identify=lambda port: None)  # a pty: cannot say what it is
    thread, result = run_in_thread(monitor)
    first.wait_for(b"INFO\r\n")
    first.send(INFO + sample(0, 0, [1, 2], [3, 4]))
    wait_until(lambda: monitor.state.samples == 1)
    first.unplug()
    time.sleep(0.2)
    second = WirePty()
    link.unlink()
    link.symlink_to(second.path)
    second.wait_for(b"INFO\r\n", timeout=20.0)  # (a loaded host retries slowly)
    # something else now sits at the path: it talks the protocol but never answers INFO
    for seq in range(5):
        second.send(sample(seq, 0, [999000, 2], [3, 4]))
    second.wait_for(b"INFO\r\nINFO\r\nINFO\r\n", timeout=20.0)  # asked three times
    wait_until(lambda: monitor.state.withheld == 5, timeout=20)
    assert monitor.state.samples == 1  # none of the stranger's samples were shown
    # then it does answer, with another model: announced, and from now on shown
    other = wire("I,fw-9,fedcba9876543210,OK,1000,dx_um;dz_um,0:T05:K;1:T12:K")
    second.send(other + sample(5, 0, [7, 8], [3, 4]))
    thread.join(35)
    assert not thread.is_alive() and result["code"] == 0
    text = out.getvalue()
    assert "cannot identify itself" in text
    assert "+999.000um" not in text
    assert "runs model fedcba9876543210, not 0123456789abcdef as before" in text
    assert monitor.state.samples == 2 and "seq=5 " in text
    second.unplug()


def test_monitor_names_the_faulted_channel_on_the_native_firmware(native_box):
    """The real firmware's STATUS words: T12's chip reports OPEN (MAX31856 SR 0x01); the
    monitor asks STATUS, names T12 and the axis that reads it (dz), and not dx."""
    binary, model_path = native_box
    box, pty = start_native(binary)
    monitor = subprocess.Popen([sys.executable, "-m", "thermal_comp.host", "monitor", pty,
                                "--model",
                                str(model_path), "--count", "6", "--json"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               cwd=ROOT)
    try:
        assert monitor.stdout is not None and box.stdin is not None
        first = json.loads(monitor.stdout.readline())
        assert first["event"] == "connected"
        feed = "S 0 3200 2816\n" * 2 + "F 1 01\n" + "S 0 3200 2816\n"
        box.stdin.write(feed.encode())
        box.stdin.flush()
        time.sleep(1.0)  # the monitor sees the fault on the third sample and asks STATUS
        box.stdin.write(b"S 0 3200 2816\n" * 3)
        box.stdin.flush()
        monitor.wait(timeout=30)
        lines = [json.loads(ln) for ln in monitor.stdout.read().splitlines()]
    finally:
        if monitor.poll() is None:
            monitor.kill()
        box.stdin.write(b"Q\n")
        box.stdin.close()
        box.wait(10)
    samples = [o for o in lines if o["type"] == "sample"]
    assert len(samples) == 6, lines
    last = samples[-1]
    assert "HOLD" in last["flags"] and "OPEN" in last["flags"], last
    assert last["faulted_channels"] == {"T12": ["OPEN"]}
    assert last["held_axes"] == ["dz_um"]
    assert last["temperatures_c"]["T12"] is None and last["temperatures_c"]["T05"] == 25.0
    faults = [o for o in lines if o["type"] == "fault"]
    assert {o["fault"] for o in faults} >= {"OPEN", "HOLD"}  # opened before STATUS named T12
    assert next(o for o in faults if o["key"] == "OPEN")["since_seq"] == 2


# ---------------------------------------------------------------- the terminal view, in tmux

class Tmux:
    """A detached tmux server of its own (private socket) running one command in one pane."""

    def __init__(self, tmp: Path, width: int, height: int, command: list[str]) -> None:
        self.socket = str(tmp / "tmux.sock")
        env = " ".join(f"{k}={v}" for k, v in (("LANG", "C.UTF-8"), ("LC_ALL", "C.UTF-8"),
                                                ("TERM", "tmux-256color")))
        shell = f"cd {ROOT} && env {env} " + " ".join(command) + " ; sleep 60"
        self.tmux("new-session", "-d", "-s", "mon", "-x", str(width), "-y", str(height),
                  shell)

    def tmux(self, *args: str) -> str:
        return subprocess.run(["tmux", "-S", self.socket, *args], capture_output=True,
                              text=True, check=True).stdout

    def capture(self) -> list[str]:
        return self.tmux("capture-pane", "-p", "-t", "mon").split("\n")[:-1]

    def wait_for(self, *needles: str, timeout: float = 10.0) -> list[str]:
        deadline = time.monotonic() + timeout
        while True:
            screen = self.capture()
            text = "\n".join(screen)
            if all(n in text for n in needles):
                return screen
            assert time.monotonic() < deadline, f"never saw {needles} on:\n{text}"
            time.sleep(0.1)

    def resize(self, width: int, height: int) -> None:
        self.tmux("resize-window", "-t", "mon", "-x", str(width), "-y", str(height))

    def close(self) -> None:
        subprocess.run(["tmux", "-S", self.socket, "kill-server"], capture_output=True)


def check_frame(screen: list[str], width: int, height: int) -> None:
    """One clean frame: at most the pane's size, the header on top exactly once, no line
    repeated (what wrapped lines used to leave behind)."""
    assert len(screen) <= height
    assert all(len(line) <= width for line in screen)
    assert screen[0].startswith("host monitor on ")
    assert sum(line.startswith("host monitor on ") for line in screen) == 1
    body = [line for line in screen if line.strip()]
    assert len(body) == len(set(body)), "\n".join(screen)


def seconds_after(screen: list[str], prefix: str) -> float:
    line = next(ln for ln in screen if prefix in ln)
    return float(line.split(prefix, 1)[1].split(" s", 1)[0])


def test_the_screen_in_tmux_at_80x24_and_200x50_on_the_native_firmware(native_box, tmp_path):
    """The curses view against the real (native) firmware in a real terminal (tmux), read back
    by capture-pane: a clean frame at 80x24 whatever wraps, the same after resizing to 200x50
    and back, a channel fault named and kept in the history after it clears, and once the box
    has stopped the age and STALE go on counting."""
    if shutil.which("tmux") is None:
        pytest.skip("tmux not installed (scripts/install-system-deps.sh installs it)")
    binary, model_path = native_box
    box, pty = start_native(binary)
    log = tmp_path / "screen.csv"
    # --retry 60: once the box has stopped, its /dev/pts number may go to another process's pty
    # (tests running side by side); the monitor would reconnect there (and say so), not here
    term = Tmux(tmp_path, 80, 24, [sys.executable, "-m", "thermal_comp.host", "monitor", pty,
                                   "--model",
                                   str(model_path), "--log", str(log), "--screen", "--retry",
                                   "60"])
    assert box.stdin is not None

    def feed(text: str) -> None:
        box.stdin.write(text.encode())
        box.stdin.flush()

    try:
        term.wait_for("matches model.json", "no sample yet")
        feed("S 0 3200 2816\n" * 3)
        screen = term.wait_for("samples 3 ")
        check_frame(screen, 80, 24)
        assert any(ln.startswith("  T05   25.00 °C   T12   22.00 °C") for ln in screen)
        # the sign note is longer than 80 columns: cut, not wrapped
        assert any(ln.endswith("…") for ln in screen)
        # T12 opens: named, its reading shown as the fault, dz (which reads it) holds
        feed("F 1 01\nS 0 3200 2816\n")
        screen = term.wait_for("OPEN(T12)", "T12      OPEN", "HOLD(dz_um)")
        feed("S 0 3200 2816\n")
        term.wait_for("samples 5 ")
        feed("F 1 00\nS 0 3200 2816\n")
        screen = term.wait_for("samples 6 ", "cleared")
        check_frame(screen, 80, 24)
        history = screen[screen.index(next(ln for ln in screen if "fault history" in ln)):]
        assert any("OPEN(T12)" in ln and "cleared" in ln and "#3" in ln and "#5" in ln
                   for ln in history), "\n".join(screen)
        assert any("HOLD(dz_um)" in ln and "cleared" in ln for ln in history)
        assert any("T12   22.00 °C" in ln for ln in screen)  # a temperature again

        term.resize(200, 50)
        # laid out again for the new width: the lines cut at 80 columns are whole now
        screen = term.wait_for("samples 6 ", "period 1000 ms", "(no ZERO reference in force)")
        check_frame(screen, 200, 50)
        assert len(screen) == 50 and max(len(ln) for ln in screen) > 150
        assert any(ln.endswith("matches model.json (CRC OK), firmware 0.1.0, period 1000 ms")
                   for ln in screen), "\n".join(screen)
        # the model's promise, in model.json's words, beside the corrections
        assert "  promised        dx_um: RMS on an unseen day ≤ 1.50 µm on 80 % of days" in screen

        feed("Q\n")  # the box stops: its port goes away
        box.stdin.close()
        box.wait(10)
        screen = term.wait_for("STALE: no sample for", "DISCONNECTED for", timeout=15)
        first = seconds_after(screen, "STALE: no sample for ")
        time.sleep(1.5)
        screen = term.capture()
        check_frame(screen, 200, 50)
        assert seconds_after(screen, "STALE: no sample for ") >= first + 1.0
        assert seconds_after(screen, "sample #5, ") >= first + 1.0  # the age counts too
        assert any("STALE (no samples)" in ln and "ACTIVE" in ln for ln in screen)

        term.resize(80, 24)  # shrinking is where a hand-made redraw left garbage
        time.sleep(0.5)
        screen = term.capture()
        check_frame(screen, 80, 24)
        assert any("STALE: no sample for" in ln for ln in screen)

        term.tmux("send-keys", "-t", "mon", "q")
        screen = term.wait_for("monitor: 6 samples", "fault history (newest first):")
    finally:
        term.close()
        if box.poll() is None:
            box.kill()
            box.wait()
    with log.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["T12"] for r in rows] == ["22.0000"] * 3 + ["", "", "22.0000"]
    assert rows[4]["faults"] == "T12=OPEN"


def test_layout_clips_to_the_width_and_gives_way_by_priority():
    from thermal_comp.host.box.screen import RED, RESET, clip, layout, visible

    main = ["host monitor on /dev/x: connected", "x" * 300, f"{RED}STALE{RESET} " + "y" * 100]
    history = [f"entry {i}" for i in range(10)]
    events = [f"event {i}" for i in range(10)]
    frame = layout(main, history, events, 24, 80)
    assert len(frame) == 24 and all(len(visible(ln)) <= 79 for ln in frame)
    assert visible(frame[1]) == "x" * 78 + "…"
    assert frame[2].startswith(RED) and visible(frame[2]).endswith("…")
    assert "fault history" in frame[3] and frame[4] == "entry 0"
    assert frame[-1] == "  event 9" and "events" in frame[14]  # the latest events, at the end
    # short: the live block first, then the newest history, the events go first
    small = layout(main, history, events, 6, 40)
    assert [visible(ln)[:5] for ln in small] == ["host ", "xxxxx", "STALE", "─── f", "entry",
                                                "entry"]
    assert layout(main, [], [], 5, 80)[3:] == ["─── fault history (newest first) " + "─" * 46,
                                               "  none since the monitor started"]
    assert layout(main, history, events, 0, 80) == [] and clip("abc", 0) == ""


def test_the_fault_history_opens_refines_and_closes_entries():
    from thermal_comp.host.box.history import LINK, SAMPLE, FaultHistory

    h = FaultHistory()
    assert [(w, e.label) for w, e in h.update(SAMPLE, {"OPEN": "OPEN", "HOLD": "HOLD"}, 10.0,
                                               3)] == [("fault", "OPEN"), ("fault", "HOLD")]
    assert h.update(SAMPLE, {"OPEN": "OPEN(T12)", "HOLD": "HOLD(dz_um)"}, 11.0, 4) == []
    h.open(LINK, "STALE", "STALE (no samples)", 11.5)
    changes = h.update(SAMPLE, {"HOLD": "HOLD(dz_um)"}, 12.0, 5)  # OPEN cleared, STALE stays
    assert [(w, e.label, e.since_seq, e.cleared_seq) for w, e in changes] == [
        ("cleared", "OPEN(T12)", 3, 5)]
    assert [e.key for e in h.active()] == ["HOLD", "STALE"]
    lines = h.lines(now=20.0)
    assert "STALE (no samples)" in lines[0] and "ACTIVE for 8.5 s" in lines[0]
    assert any("OPEN(T12)" in ln and "#5 after 2.0 s" in ln for ln in lines)
    h.close(LINK, "STALE", 21.0)
    assert [e.key for e in h.active()] == ["HOLD"]
