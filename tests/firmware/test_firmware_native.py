"""The real firmware on the native board (ASan + UBSan build), driven over stdin and its pty,
every line judged by contract/protocol.py. Expectations come from the host: codegen.fixed for the
model, firmware/test/gen_test_model.py's documented output rules for hold/slew/clamp/status.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from firmware_support import Box, box_defaults, build, load_generator

from thermal_comp.contract import protocol as p

gen = load_generator()


@pytest.fixture(scope="module")
def fw(tmp_path_factory):
    """(module generator, generated header, native binary, model dict) for the test model."""
    from thermal_comp import codegen

    tmp = tmp_path_factory.mktemp("fw")
    model = gen.test_model()
    header = codegen.generate(model)
    (tmp / "model.h").write_text(header.text)
    build(tmp / "model.h", tmp / "native")
    return {"header": header, "binary": tmp / "native" / "thermal_box", "model": model,
            "tmp": tmp}


def feed_session(box: Box, s: dict[str, np.ndarray], start: int = 0,
                 stop: int | None = None) -> None:
    """S lines for samples [start, stop), preceded by F lines where a chip's fault register
    changes."""
    n, n_ch = s["codes"].shape
    stop = n if stop is None else stop
    prev = s["sr"][start - 1] if start > 0 else np.zeros(n_ch, dtype=np.int64)
    out = []
    for i in range(start, stop):
        for c in range(n_ch):
            if s["sr"][i, c] != prev[c]:
                out.append(f"F {c} {int(s['sr'][i, c]):02X}\n")
        prev = s["sr"][i]
        out.append("S " + " ".join(str(int(v)) for v in [s["aux"][i], *s["codes"][i]]) + "\n")
    box.feed("".join(out))


def test_session_matches_host_expectation_bit_for_bit(fw):
    s = gen.session(np.random.default_rng(gen.SEED))
    s["present"][:] = True  # the feed cannot silence a chip mid-run
    s["aux_ok"][:] = True  # nor fail the ADC
    cfg = box_defaults()
    step = max(1, (cfg["BOX_SLEW_NM_PER_S"] * 1000 + 500) // 1000)
    e = gen.expected(fw["model"], s, cfg["BOX_MAX_CORRECTION_NM"], step,
                     bool(cfg["BOX_COLD_START_SLEW"]))
    box = Box(fw["binary"])
    lines, start = [], 0
    for z in (*gen.ZERO_BEFORE, gen.N_SAMPLES):  # the CNC side sends ZERO between samples
        feed_session(box, s, start, z)
        lines += box.lines(z - start)
        if z < gen.N_SAMPLES:
            box.send(p.encode_command("ZERO"))
            assert p.decode(box.lines(1)[0]) == p.Ack("ZERO", z - 1)
        start = z
    rc, err = box.finish()
    assert rc == 0, err
    samples = [p.decode(line) for line in lines]  # every line passes the decoder's CRC check
    assert [m.seq for m in samples] == list(range(gen.N_SAMPLES))
    got_out = np.array([m.corrections_nm for m in samples])
    got_status = np.array([m.status for m in samples])
    bad = np.flatnonzero((got_out != e["out"]).any(axis=1) | (got_status != e["status"]))
    assert bad.size == 0, (f"first mismatch at sample {bad[0]}: {samples[bad[0]]}, expected "
                           f"{e['out'][bad[0]].tolist()} status {e['status'][bad[0]]:04X}")
    assert np.array_equal(np.array([m.temp_codes for m in samples]), s["codes"])
    assert got_status.max() > 0  # the session exercised faults


def test_info_status_and_rate_over_the_pty(fw):
    header = fw["header"]
    box = Box(fw["binary"])
    box.send(p.encode_command("INFO") + p.encode_command("STATUS"))
    info, status = (p.decode(line) for line in box.lines(2))
    assert info == p.Info(
        "0.1.0", header.model.model_hash, True, 1000, ("dx_um", "dy_um", "dz_um"),
        tuple(p.Channel(c["channel"], c["sensor"], c["tc_type"])
              for c in fw["model"]["channels"]))
    # the estimator per axis (issue 42): '-' for an axis without a service block (MEAS OFF)
    service = tuple(None if "service" not in ax else p.AxisService(0, None, 0, 0)
                    for ax in fw["model"]["axes"].values())
    assert status == p.StatusReport(p.Status.NO_DATA, 0, 0, (0,) * 8, service=service)

    box.send(p.encode_command("RATE", 4))
    assert p.decode(box.lines(1)[0]) == p.Ack("RATE", 4)
    box.feed("S 1000 " + " ".join(["2560"] * 8) + "\n" * 1)
    box.feed(("S 1000 " + " ".join(["2560"] * 8) + "\n") * 8)
    seqs = [p.decode(line).seq for line in box.lines(3)]
    assert seqs == [0, 4, 8]
    box.send(b"STATUS\r\n")
    report = p.decode(box.lines(1)[0])
    assert report.seq == 8 and report.uptime_s == 9
    assert box.finish()[0] == 0


@pytest.mark.parametrize(("raw", "reason"), [
    (b"RATE 0\r\n", "BAD_ARG"),
    (b"RATE 3601\n", "BAD_ARG"),
    (b"RATE five\n", "BAD_ARG"),
    (b"info\n", "UNKNOWN"),
    (b"RESET\r\n", "UNKNOWN"),
    (b"X" * 65 + b"\n", "TOO_LONG"),
    (b"S" * 5000 + b"\r\n", "TOO_LONG"),
    (b"INF\xcfO\n", "BINARY"),
    (b"\x00\x01\x02\xff\r\n", "BINARY"),
])
def test_malformed_commands_get_one_error_each(fw, raw, reason):
    box = Box(fw["binary"])
    box.send(raw)
    assert p.decode(box.lines(1)[0]) == p.ErrorReply(reason)
    box.send(b"INFO\n")  # and the box still listens
    assert isinstance(p.decode(box.lines(1)[0]), p.Info)
    assert box.silent(0.2)
    assert box.finish()[0] == 0


def test_faults_set_status_bits_and_hold(fw):
    box = Box(fw["binary"])
    n = 0

    def ok(t05: str = "2560") -> str:
        """Every channel at 20 degC, T05 as given; T07 (its stuck check: the same code 12
        times in a row is STUCK) dithers by one code, as a live thermocouple does."""
        nonlocal n
        n += 1
        return " ".join(["2560"] * 4 + [t05, "2560", str(2560 + n % 2), "2560"])

    box.feed("".join(f"S 1000 {ok()}\n" for _ in range(80)))  # the cold-start walk is over
    settled = [p.decode(line) for line in box.lines(80)][-1]
    assert settled.status == 0
    box.feed("F 1 01\n" + f"S 1000 {ok()}\n")  # T02 open: dx holds
    m = p.decode(box.lines(1)[0])
    assert m.flags == p.Status.OPEN | p.Status.HOLD
    assert m.corrections_nm[0] == settled.corrections_nm[0]
    box.feed("F 1 00\nF 6 40\n" + f"S 1000 {ok()}\n")  # T07 thermocouple range: dz holds
    assert p.decode(box.lines(1)[0]).flags == p.Status.TC_FAULT | p.Status.HOLD
    box.feed("F 6 00\n" + f"S 1000 {ok('30000')}\n")
    assert p.decode(box.lines(1)[0]).flags == p.Status.RANGE | p.Status.HOLD  # T05 > 200 degC
    box.feed(f"S 13000 {ok()}\n")  # spindle above 12000 rpm
    assert p.decode(box.lines(1)[0]).flags == p.Status.AUX_FAULT | p.Status.HOLD
    box.feed(f"S 1000 {ok()}\n")
    assert p.decode(box.lines(1)[0]).status == 0
    box.send(b"STATUS\n")
    assert p.decode(box.lines(1)[0]).channel_faults == (0,) * 8
    frozen = " ".join(["2560"] * 6 + ["2570", "2560"])  # T07 freezes: stuck at the 12th
    box.feed(f"S 1000 {frozen}\n" * 12)
    lines = [p.decode(line) for line in box.lines(12)]
    assert [bool(m.flags & p.Status.HOLD) for m in lines] == [False] * 11 + [True]
    box.send(b"STATUS\n")
    assert p.decode(box.lines(1)[0]).channel_faults == (0,) * 6 + (p.ChannelFault.STUCK, 0)
    assert box.finish()[0] == 0


def test_missing_chips_are_reported_not_responding(fw):
    box = Box(fw["binary"])
    box.feed("S 1000 2560 2560 2560 2560 2560 2560\n")  # only 6 chips on the bus
    m = p.decode(box.lines(1)[0])
    assert m.flags & p.Status.TC_FAULT and m.flags & p.Status.HOLD
    assert m.temp_codes[6:] == (0, 0)
    box.send(b"STATUS\n")
    faults = p.decode(box.lines(1)[0]).channel_faults
    assert faults == (0,) * 6 + (p.ChannelFault.NO_RESPONSE,) * 2
    assert box.finish()[0] == 0


def test_watchdog_reset_is_flagged_on_every_line(fw):
    box = Box(fw["binary"], "--wdt-reset")
    box.feed(("S 1000 " + " ".join(["2560"] * 8) + "\n") * 3)
    assert all(p.decode(line).flags & p.Status.WDT_RESET for line in box.lines(3))
    assert box.finish()[0] == 0


def test_stuck_loop_is_reset_by_the_watchdog(fw):
    box = Box(fw["binary"], "--hang-after-samples", "2")
    box.feed(("S 1000 " + " ".join(["2560"] * 8) + "\n") * 5)
    lines = [p.decode(line) for line in box.lines(4)]
    # samples 0 and 1, then the bus locks up on the third: a warm reset; the box resumes from
    # its retained memory (seq counts on, WDT_RESET from then on, no new power-up: no NO_DATA)
    assert [m.seq for m in lines] == [0, 1, 2, 3]
    assert [bool(m.flags & p.Status.WDT_RESET) for m in lines] == [False, False, True, True]
    assert not any(m.flags & p.Status.NO_DATA for m in lines[2:])
    rc, err = box.finish()
    assert rc == 0 and "watchdog reset" in err


def test_model_crc_mismatch_means_no_corrections(fw):
    tmp = fw["tmp"]
    (tmp / "bad.h").write_text(gen.corrupt(fw["header"].text))
    build(tmp / "bad.h", tmp / "native-bad")
    box = Box(tmp / "native-bad" / "thermal_box")
    box.send(b"INFO\n")
    info = p.decode(box.lines(1)[0])
    assert info.crc_ok is False
    box.feed("S 1000 " + " ".join(str(2560 + c) for c in range(8)) + "\n")
    m = p.decode(box.lines(1)[0])
    assert m == p.Sample(0, p.Status.MODEL_BAD, (), tuple(2560 + c for c in range(8)))
    assert box.finish()[0] == 0


@pytest.mark.parametrize(("feed", "message"), [
    ("S 1000 2560\nS x 2560\n", "feed line 2 (sample 1): S: aux value 'x'"),
    ("S 1000 262144\n",
     "feed line 1 (sample 0): S: code '262144' is not an integer in -262144..262143"),
    ("S 1000 1 2\nS 1000 1\n", "feed line 2 (sample 1): S: 1 codes, the first S line had 2"),
    ("F 9 01\n", "feed line 1 (before sample 0): F: channel '9'"),
    ("F 1 1FF\n", "feed line 1 (before sample 0): F: fault status '1FF'"),
    ("S 1000 2560\nF 9 01\n", "feed line 2 (before sample 1): F: channel '9'"),
    ("\nT 1\n", "feed line 2 (before sample 0): unknown command 'T 1'"),
    ("S 1000\n", "feed line 1 (sample 0): S: no temperature codes"),
])
def test_bad_feed_lines_stop_with_a_message_naming_the_line(fw, feed, message):
    box = Box(fw["binary"])
    box.feed(feed)
    rc, err = box.finish()
    assert rc == 2
    assert message in err


def test_end_of_feed_exits_cleanly(fw):
    box = Box(fw["binary"], keep_master=True)  # the board may exit before the line is read
    box.feed("S 1000 2560 2560 2560 2560 2560 2560 2560 2560")  # last line without newline
    box.close_feed()
    assert p.decode(box.lines(1)[0]).seq == 0  # the unterminated line still counts
    assert box.proc.wait(10) == 0
    box.finish()


def test_a_slow_reader_loses_no_line(fw):
    """The pty fills up while nobody reads (a loaded CI machine): the board waits, it never
    drops a line (issue 14, "In CI")."""
    import threading
    import time

    n = 20_000  # ~1.3 MB of sample lines, far more than a pty buffers
    box = Box(fw["binary"])
    feed = "".join(f"S {i % 12000} " + " ".join(str(2560 + (i + c) % 50) for c in range(8))
                   + "\n" for i in range(n))
    # fed from a thread: the board stops reading its feed while it waits on the full pty
    feeder = threading.Thread(target=box.feed, args=(feed,), daemon=True)
    feeder.start()
    time.sleep(1.0)  # the board is blocked on a full pty by now
    assert feeder.is_alive()  # ... and so is the feed behind it
    box.port.timeout = 0.5
    chunks = []
    while sum(c.count(b"\n") for c in chunks) < n:
        data = box.port.read(1 << 16)
        assert data, "the board stopped sending"
        chunks.append(data)
    box.port.timeout = 20.0
    feeder.join(10)
    lines = b"".join(chunks).splitlines(keepends=True)
    rc, err = box.finish()
    assert rc == 0, err
    assert [p.decode(line).seq for line in lines] == list(range(n))


def test_pty_fd_must_be_a_pty_master(fw, tmp_path):
    import os
    import subprocess

    fd = os.open(tmp_path / "plain", os.O_RDWR | os.O_CREAT)
    try:
        r = subprocess.run([str(fw["binary"]), "--pty-fd", str(fd)], capture_output=True,
                           text=True, pass_fds=(fd,), timeout=10)
    finally:
        os.close(fd)
    assert r.returncode == 1 and "is not a pseudo-terminal master" in r.stderr


def test_help_names_the_options(fw):
    import subprocess

    r = subprocess.run([str(fw["binary"]), "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "--wdt-reset" in r.stdout and "--pty-fd" in r.stdout
    r = subprocess.run([str(fw["binary"]), "--bogus"], capture_output=True, text=True)
    assert r.returncode == 2 and re.search(r"unknown option '--bogus'", r.stderr)


def test_info_with_longest_names_fits_one_line(tmp_path):
    from thermal_comp import codegen

    model = gen.test_model()
    long = {c["sensor"]: f"{c['sensor']}_" + "x" * (31 - len(c["sensor"]))
            for c in model["channels"]}
    for c in model["channels"]:
        c["sensor"] = long[c["sensor"]]
    for axis in list(model["axes"]):
        ax = model["axes"].pop(axis)
        for t in ax["terms"]:
            t["source"] = long.get(t.get("source"), t.get("source"))
        model["axes"][axis + "_" + "y" * (31 - len(axis))] = ax
    header = codegen.generate(model)
    (tmp_path / "model.h").write_text(header.text)
    build(tmp_path / "model.h", tmp_path / "native")
    box = Box(tmp_path / "native" / "thermal_box")
    box.send(b"INFO\n")
    info = p.decode(box.lines(1)[0])
    assert all(len(name) == 32 for name in info.axes) and len(info.axes) == 3
    assert [c.sensor for c in info.channels] == [c["sensor"] for c in model["channels"]]
    assert box.finish()[0] == 0
