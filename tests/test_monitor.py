"""`host monitor` over pseudo-terminals: noise on the wire, a lost and re-plugged port, the model
hash check, and the CSV log, with every expected value computed here from the bytes sent."""

from __future__ import annotations

import binascii
import csv
import io
import os
import select
import threading
import time
from pathlib import Path

import pytest

from host.cli import main as host_main
from host.monitor import Monitor, render


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
    monitor = Monitor(box.path, count=4, log=log, out=out, ansi=False,
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
                       "host_unix_s"]
    for row, (seq, status, corr, codes) in zip(rows[1:], good, strict=True):
        assert float(row[0]) == seq * 1.0 and int(row[1]) == seq
        assert int(row[2], 16) == status
        assert [float(v) for v in row[3:5]] == [c / 1000 for c in corr]
        assert [float(v) for v in row[5:7]] == pytest.approx([c / 128 for c in codes], abs=1e-4)

    text = out.getvalue()
    assert "\x1b[" not in text  # plain mode: no escape sequences in a pipe
    assert "status=0220[OPEN,NO_DATA]" in text
    assert "dx_um=+1.234um" in text and "T12=-0.09C" in text
    assert text.count("bad line #") == 4
    box.unplug()


def test_existing_log_is_appended_and_a_different_layout_is_refused(tmp_path):
    log = tmp_path / "live.csv"
    for expected_rows in (2, 3):
        box = WirePty()
        monitor = Monitor(box.path, count=1, log=log, out=io.StringIO(), ansi=False)
        thread, result = run_in_thread(monitor)
        box.wait_for(b"INFO\r\n")
        box.send(INFO + sample(expected_rows, 0, [1, 2], [3, 4]))
        thread.join(10)
        assert result["code"] == 0
        assert len(log.read_text().splitlines()) == expected_rows  # one header only
        box.unplug()

    box = WirePty()
    other = wire("I,fw-1.2.3,0123456789abcdef,OK,1000,dy_um,0:T05:K")
    monitor = Monitor(box.path, count=1, log=log, out=io.StringIO(), ansi=False)
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
    monitor = Monitor(str(link), count=4, out=out, ansi=False, retry_s=0.05,
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
    second.wait_for(b"INFO\r\n")  # asked again after reconnecting
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
    monitor = Monitor(box.path, count=1, out=out, ansi=False, expected_hash="ffffffffffffffff")
    thread, result = run_in_thread(monitor)
    box.wait_for(b"INFO\r\n")
    box.send(INFO + sample(0, 0, [1, 2], [3, 4]))
    thread.join(10)
    assert result["code"] == 1
    assert "MISMATCH: model.json is ffffffffffffffff" in out.getvalue()
    box.unplug()


def test_terminal_display_redraws_in_place():
    box = WirePty()
    out = io.StringIO()
    monitor = Monitor(box.path, count=2, out=out, ansi=True)
    thread, result = run_in_thread(monitor)
    box.wait_for(b"INFO\r\n")
    box.send(INFO + sample(7, 0x0008, [-250, 99999], [3200, 3456]) + b"garbage\r\n")
    time.sleep(0.3)
    box.send(sample(8, 0x0008, [-250, 99999], [3200, 3456]))
    thread.join(10)
    assert result["code"] == 0
    text = out.getvalue()
    assert "\x1b[J" in text and "F\x1b[J" in text  # cursor moved back up and frame cleared
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
