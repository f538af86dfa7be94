"""thermalcomp's rules without HAL: config errors, hold, walk, sequence, stale (cnc/thermalcomp.py).

The LinuxCNC side (pins, resync) is exercised on a real LinuxCNC by tests/test_cnc.py; here the
lines come from the project's encoder, as the box writes them.
"""

from __future__ import annotations

import pytest

from cnc import thermalcomp as tc
from cnc.thermalcomp import protocol

CONF = """
[box]
port = /dev/null
stale_periods = 3
slew_nm_per_s = 100
[axis.z]
box_axis = dz_um
sign = -1
nm_per_count = 1
[axis.x]
box_axis = dx_um
sign = +1
nm_per_count = 10
"""


def _comp(tmp_path, text: str = CONF) -> tc.Compensator:
    path = tmp_path / "thermalcomp.conf"
    path.write_text(text)
    comp = tc.Compensator(tc.load_config(path), log=lambda msg: None)
    comp.take_info(protocol.Info("0.1.0", "abc", True, 1000, ("dx_um", "dz_um"), ()))
    return comp


def _line(comp, seq: int, dx: int, dz: int, status: int = 0, now: float = 0.0) -> None:
    raw = protocol.encode_sample(seq, status, [dx, dz], [2560]).rstrip(b"\r\n")
    tc.handle_line(comp, tc.Port("/dev/null", 115200), raw, now)


def _want(comp) -> dict[str, int]:
    return {a.letter: a.want for a in comp.cfg.axes}


def test_sign_and_count_size_map_box_axes_to_linuxcnc_axes(tmp_path):
    comp = _comp(tmp_path)
    _line(comp, 0, 55, 40)
    assert _want(comp) == {"z": -40, "x": 6}  # x: 55 nm in 10 nm counts, rounded


def test_a_box_fault_holds_every_axis_and_the_walk_back_is_limited(tmp_path):
    comp = _comp(tmp_path)
    _line(comp, 0, 0, 40)
    _line(comp, 1, 0, 900, status=int(protocol.Status.HOLD | protocol.Status.OPEN))
    assert _want(comp)["z"] == -40 and comp.fault and comp.holds == 1
    _line(comp, 2, 0, 900)  # 100 nm/s x 1 s period: at most 100 counts per line
    assert _want(comp)["z"] == -140 and comp.walking
    for seq in range(3, 12):
        _line(comp, seq, 0, 900)
    assert _want(comp)["z"] == -900 and not comp.walking


def test_a_corrupted_line_is_refused_and_changes_nothing(tmp_path):
    comp = _comp(tmp_path)
    _line(comp, 0, 0, 40)
    raw = bytearray(protocol.encode_sample(1, 0, [0, 41], [2560]).rstrip(b"\r\n"))
    raw[raw.index(b"41")] = ord("9")
    tc.handle_line(comp, tc.Port("/dev/null", 115200), bytes(raw), 0.0)
    assert comp.bad_lines == 1 and _want(comp)["z"] == -40
    _line(comp, 2, 0, 42)
    assert comp.lost_lines == 1 and _want(comp)["z"] == -42


def test_stale_after_the_configured_number_of_periods(tmp_path):
    comp = _comp(tmp_path)
    _line(comp, 0, 0, 40, now=10.0)
    comp.check_stale(12.9)
    assert not comp.stale
    comp.check_stale(13.1)
    assert comp.stale
    _line(comp, 1, 0, 41, now=13.2)
    assert not comp.stale and _want(comp)["z"] == -41


def test_a_box_restart_holds_while_the_box_walks_from_0(tmp_path):
    comp = _comp(tmp_path)
    for seq, dz in enumerate([0, 100, 200, 300]):
        _line(comp, seq, 0, dz)
    slew = int(protocol.Status.SLEW)
    _line(comp, 0, 0, 100, status=slew)  # rebooted box: seq 0, walking up from 0 itself
    _line(comp, 1, 0, 200, status=slew)
    assert comp.restarts == 1 and _want(comp)["z"] == -300 and comp.holds == 2
    _line(comp, 2, 0, 310)  # tracking again: the offset follows
    assert _want(comp)["z"] == -310


def test_a_box_restart_without_cold_start_walk_is_walked_to(tmp_path):
    comp = _comp(tmp_path)
    for seq, dz in enumerate([0, 100, 200, 300]):
        _line(comp, seq, 0, dz)
    _line(comp, 0, 0, 0)  # no SLEW: a box built with BOX_COLD_START_SLEW=0
    assert comp.restarts == 1 and _want(comp)["z"] == -200  # one 100 nm step, not to 0


@pytest.mark.parametrize("text, needle", [
    ("[axis.z]\nbox_axis = dz_um\nsign = -1\n", "no [box] section"),
    ("[box]\nport = /dev/x\n", "no [axis.<letter>] section"),
    ("[box]\nport = /dev/x\n[axis.z]\nbox_axis = dz_um\nsign = 2\n", "sign = '2'"),
    ("[box]\nport = /dev/x\n[axis.q]\nbox_axis = dz_um\nsign = -1\n", "axis letter"),
    ("[box]\nport = /dev/x\nstale_periods = abc\n[axis.z]\nbox_axis = a\nsign = -1\n",
     "stale_periods = 'abc'"),
    ("[box]\n[axis.z]\nbox_axis = a\nsign = -1\n", "needs 'port'"),
])
def test_config_errors_name_the_file_section_and_key(tmp_path, text, needle):
    path = tmp_path / "bad.conf"
    path.write_text(text)
    with pytest.raises(tc.ConfigError) as err:
        tc.load_config(path)
    assert needle in str(err.value) and str(path) in str(err.value)


def test_the_shipped_config_loads():
    cfg = tc.load_config(tc.Path(__file__).resolve().parents[1] / "cnc" / "config"
                         / "thermalcomp.conf")
    assert [(a.letter, a.box_axis, a.sign) for a in cfg.axes] == [
        ("x", "dx_um", -1), ("y", "dy_um", -1), ("z", "dz_um", -1)]
    assert cfg.port == "/dev/ttyUSB0" and cfg.period_s is None


def test_zero_changes_the_datum_at_once(tmp_path):
    comp = _comp(tmp_path)
    for seq in range(3):
        _line(comp, seq, 0, 100 * (seq + 1))
    assert _want(comp)["z"] == -300
    comp.zeroed(2)  # what handle_line does with $OK,ZERO,2 (decoded by contract.protocol)
    assert comp.zero_acks == 1 and comp.zero_seq == 2
    _line(comp, 3, 0, 0, status=tc.REFERENCED)
    assert _want(comp)["z"] == 0 and not comp.walking  # not 100 nm a line: a datum change
    _line(comp, 4, 0, 250, status=tc.REFERENCED)
    assert _want(comp)["z"] == -100  # after it, the walk limit again
