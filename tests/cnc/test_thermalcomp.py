"""thermalcomp's rules without HAL: config errors, hold, walk, sequence, stale (cnc/thermalcomp.py).

The LinuxCNC side (pins, resync) is exercised on a real LinuxCNC by tests/cnc/test_cnc.py; here the
lines come from the project's encoder, as the box writes them. Issue 41's rules (no single event
makes the tool error worse than the clean run by more than one step limit; where the component
cannot know, it holds and says why) each have a test below; their expectations come from the
rules (step limits, bounds, held values), not from the component's output.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from thermal_comp.cnc import thermalcomp as tc
from thermal_comp.cnc.thermalcomp import protocol
from thermal_comp.contract import model_file

ROOT = Path(__file__).resolve().parents[2]
HASH = "0123456789abcdef"
# z: the step limit (250 nm) is above the walk-back slew (100 nm/s x 1 s) in CONF, so walks go
# at 100 nm per line; x: 80 nm = 8 counts of 10 nm.
CONF = f"""
[box]
port = /dev/null
stale_periods = 3
slew_nm_per_s = 100
model_hash = {HASH}
[axis.z]
box_axis = dz_um
sign = -1
nm_per_count = 1
max_step_um = 0.25
[axis.x]
box_axis = dx_um
sign = +1
nm_per_count = 10
max_step_um = 0.08
"""
# the step limits bind, not the slew (10000 nm per line)
FAST = CONF.replace("slew_nm_per_s = 100", "slew_nm_per_s = 10000")
Z_STEP, X_STEP = 250, 8  # counts per line under FAST


def _info(model_hash: str = HASH) -> protocol.Info:
    return protocol.Info("0.1.0", model_hash, True, 1000, ("dx_um", "dz_um"), ())


def _comp(tmp_path, text: str = CONF, logs: list[str] | None = None) -> tc.Compensator:
    path = tmp_path / "thermalcomp.conf"
    path.write_text(text)
    comp = tc.Compensator(tc.load_config(path),
                          log=(lambda msg: logs.append(msg)) if logs is not None else
                          (lambda msg: None))
    comp.take_info(_info())
    return comp


def _raw(seq: int, dx: int, dz: int, status: int = 0) -> bytes:
    return protocol.encode_sample(seq, status, [dx, dz], [2560]).rstrip(b"\r\n")


def _line(comp, seq: int, dx: int, dz: int, status: int = 0, now: float = 0.0) -> None:
    tc.handle_line(comp, tc.Port("/dev/null", 115200), _raw(seq, dx, dz, status), now)


def _track(comp, dz_values, dx: int = 0, first_seq: int = 0) -> int:
    """Feed in-order lines (each change within the step limits); returns the next seq."""
    seq = first_seq
    for dz in dz_values:
        _line(comp, seq, dx, dz)
        seq += 1
    return seq


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
    assert comp.needs_info()  # a restarted box may carry another model: asked again
    comp.take_info(_info())
    _line(comp, 2, 0, 310)  # tracking again: the offset follows
    assert _want(comp)["z"] == -310


def test_a_box_restart_without_cold_start_walk_is_walked_to(tmp_path):
    comp = _comp(tmp_path)
    for seq, dz in enumerate([0, 100, 200, 300]):
        _line(comp, seq, 0, dz)
    _line(comp, 0, 0, 0)  # no SLEW: a box built with BOX_COLD_START_SLEW=0
    _line(comp, 1, 0, 0)  # the second line confirms the restart
    comp.take_info(_info())  # the component asked INFO again: the same model
    _line(comp, 2, 0, 0)
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


def test_the_shipped_config_loads_and_refuses_to_drive_without_a_model():
    cfg = tc.load_config(ROOT / "thermal_comp" / "cnc" / "config" / "thermalcomp.conf")
    assert [(a.letter, a.box_axis, a.sign) for a in cfg.axes] == [
        ("x", "dx_um", -1), ("y", "dy_um", -1), ("z", "dz_um", -1)]
    assert cfg.port == "/dev/ttyUSB0" and cfg.period_s is None
    assert cfg.model_hash is None and cfg.max_abs_um == 200.0  # `model =` is to be filled in
    logs: list[str] = []
    comp = tc.Compensator(cfg, log=logs.append)
    comp.take_info(protocol.Info("0.1.0", HASH, True, 1000, ("dx_um", "dy_um", "dz_um"), ()))
    raw = protocol.encode_sample(0, 0, [500, 500, 500], [2560]).rstrip(b"\r\n")
    tc.handle_line(comp, tc.Port("/dev/null", 115200), raw, 0.0)
    assert all(a.want == 0 for a in cfg.axes) and comp.holding and comp.model_mismatch
    assert any("no expected model hash" in m for m in logs)


def test_zero_changes_the_datum_at_once(tmp_path):
    comp = _comp(tmp_path)
    for seq in range(3):
        _line(comp, seq, 0, 100 * (seq + 1))
    assert _want(comp)["z"] == -300
    comp.zero_sent()  # the zero pin's rising edge
    comp.zeroed(2)  # what handle_line does with $OK,ZERO,2 (decoded by contract.protocol)
    assert comp.zero_acks == 1 and comp.zero_seq == 2
    _line(comp, 3, 0, 0, status=tc.REFERENCED)
    assert _want(comp)["z"] == 0 and not comp.walking  # not 100 nm a line: a datum change
    _line(comp, 4, 0, 250, status=tc.REFERENCED)
    assert _want(comp)["z"] == -100  # after it, the walk limit again


# ---- issue 41: never worse than no compensation ------------------------------------------

def test_a_forged_line_moves_each_axis_by_one_step_limit_at_most(tmp_path):
    comp = _comp(tmp_path, FAST)
    seq = _track(comp, [0, 100, 200], dx=50)
    before = _want(comp)
    assert before == {"z": -200, "x": 5}
    # CRC-valid, in sequence, 60 um on both axes (the line of the issue)
    _line(comp, seq, 60_000, 60_200)
    after = _want(comp)
    assert after["z"] == before["z"] - Z_STEP and after["x"] == before["x"] + X_STEP
    _line(comp, seq + 1, 50, 200)  # the next good line puts it back
    assert _want(comp) == before and not comp.walking


def test_a_forged_seq_jump_is_taken_as_a_stray_not_a_restart(tmp_path):
    comp = _comp(tmp_path, FAST)
    seq = _track(comp, [0, 100, 200])
    _line(comp, seq + 5000, 0, -60_000)  # forged: far ahead, another value
    assert _want(comp)["z"] == -200 + Z_STEP
    _line(comp, seq, 0, 210)  # the box's own next line: behind the forged one
    _line(comp, seq + 1, 0, 220)
    assert comp.restarts == 0 and comp.lost_lines == 0 and comp.bad_lines == 1
    assert _want(comp)["z"] == -220 and not comp.holding


def test_a_forged_line_going_back_is_held_and_not_a_restart(tmp_path):
    comp = _comp(tmp_path, FAST)
    seq = _track(comp, [0, 100, 200])
    _line(comp, 0, 0, -60_000)  # forged seq 0: held until the next line says what it was
    assert _want(comp)["z"] == -200 and comp.holding
    _line(comp, seq, 0, 210)  # the stream goes on: the forged line was a stray
    assert comp.restarts == 0 and comp.bad_lines == 1 and _want(comp)["z"] == -210
    assert not comp.holding


def test_a_model_hash_mismatch_holds_every_axis_and_names_both_hashes(tmp_path):
    logs: list[str] = []
    comp = _comp(tmp_path, FAST, logs)
    seq = _track(comp, [0, 100], dx=40)
    held = _want(comp)
    comp.take_info(_info("fedcba9876543210"))  # another model on the box
    seq = _track(comp, [150, 200], dx=60, first_seq=seq)
    assert _want(comp) == held and comp.holding and comp.model_mismatch
    assert comp.needs_info()  # asked again: a forged INFO costs a second, not the shift
    assert any("fedcba9876543210" in m and HASH in m for m in logs)
    comp.take_info(_info())  # the right model again: follow, within the step limits
    _track(comp, [200], dx=60, first_seq=seq)
    assert _want(comp) == {"z": -200, "x": 6} and not comp.model_mismatch


def test_before_any_info_every_axis_holds(tmp_path):
    path = tmp_path / "thermalcomp.conf"
    path.write_text(FAST)
    comp = tc.Compensator(tc.load_config(path), log=lambda msg: None)
    _track(comp, [0, 100])
    assert _want(comp) == {"z": 0, "x": 0} and comp.holding and comp.needs_info()


def test_model_path_gives_the_hash_and_the_step_limits(tmp_path):
    model = _model_dict()
    model_file.write_model(model, tmp_path / "model.json")
    text = FAST.replace(f"model_hash = {HASH}", "model = model.json")  # relative to the conf
    text = text.replace("max_step_um = 0.25\n", "").replace("max_step_um = 0.08\n", "")
    path = tmp_path / "thermalcomp.conf"
    path.write_text(text)
    cfg = tc.load_config(path)
    assert cfg.model_hash == model_file.model_hash(model) == model["model_hash"]
    steps = {a.box_axis: a.step_nm for a in cfg.axes}
    # dz_um: 0.3125 um rounded up to nm as codegen does; dx_um has none: 1 um/s x 2 s
    assert steps == {"dz_um": 313, "dx_um": 2000}
    # a step limit in the config can only tighten the model's
    path.write_text(text.replace("nm_per_count = 1\n", "nm_per_count = 1\nmax_step_um = 0.1\n"))
    assert {a.box_axis: a.step_nm for a in tc.load_config(path).axes}["dz_um"] == 100


def _model_dict() -> dict:
    return {
        "schema": "thermal-model/1", "tool_version": "0.1.0", "sample_period_s": 2.0,
        "channels": [{"channel": 0, "sensor": "T01", "tc_type": "K", "min_c": -40.0,
                      "max_c": 200.0}],
        "aux": [],
        "axes": {"dx_um": {"unit": "um", "intercept": 0.0,
                           "terms": [{"kind": "temp", "source": "T01", "coef": 1.0}]},
                 "dz_um": {"unit": "um", "intercept": 1.0, "max_step_um": 0.3125,
                           "terms": [{"kind": "temp", "source": "T01", "coef": 2.0}]}},
        "training": {"runs": ["run.csv"], "targets": ["dx_um", "dz_um"], "sensors": "T*",
                     "aux": []},
    }


@pytest.mark.parametrize("change, needle", [
    (lambda t: t.replace("max_step_um = 0.08\n", ""), "needs 'max_step_um'"),
    (lambda t: t.replace("max_step_um = 0.08", "max_step_um = 0.005"), "larger than the axis"),
    (lambda t: t.replace("max_step_um = 0.08", "max_step_um = -1"), "must be positive"),
    (lambda t: t.replace("slew_nm_per_s = 10000", "slew_nm_per_s = 10000\nmax_abs_um = 0"),
     "max_abs_um = 0 must be positive"),
    (lambda t: t.replace(f"model_hash = {HASH}", "model = nowhere.json"), "model = "),
])
def test_step_limit_and_model_config_errors(tmp_path, change, needle):
    path = tmp_path / "thermalcomp.conf"
    path.write_text(change(FAST))
    with pytest.raises(tc.ConfigError) as err:
        tc.load_config(path)
    assert needle in str(err.value) and str(path) in str(err.value)


def test_a_model_and_a_hash_that_disagree_are_refused(tmp_path):
    model_file.write_model(_model_dict(), tmp_path / "model.json")
    path = tmp_path / "thermalcomp.conf"
    path.write_text(FAST.replace(f"model_hash = {HASH}",
                                 f"model = {tmp_path / 'model.json'}\nmodel_hash = {HASH}"))
    with pytest.raises(tc.ConfigError, match="which one is it"):
        tc.load_config(path)


def test_walking_back_after_a_hold_keeps_to_min_of_step_limit_and_slew(tmp_path):
    hold = int(protocol.Status.HOLD | protocol.Status.OPEN)
    for text, z_step in ((CONF, 100), (FAST, Z_STEP)):  # slew 100 nm/line; step 250 nm/line
        comp = _comp(tmp_path, text)
        seq = _track(comp, [0, 40])
        for k in range(10):
            _line(comp, seq, 0, 40 + 500 * k, status=hold)
            seq += 1
        assert _want(comp)["z"] == -40
        wants = [-40]
        for _ in range(60):
            _line(comp, seq, 0, 5000)
            seq += 1
            wants.append(_want(comp)["z"])
        steps = [abs(b - a) for a, b in zip(wants, wants[1:], strict=False)]
        assert max(steps) == z_step and wants[-1] == -5000


@pytest.mark.parametrize("bit", ["CLAMP", "NO_REF", "BEYOND", "NO_DATA", "IMPLAUSIBLE",
                                 "MODEL_BAD"])
def test_each_hold_bit_holds_every_axis(tmp_path, bit):
    comp = _comp(tmp_path, FAST)
    seq = _track(comp, [0, 100], dx=30)
    held = _want(comp)
    _line(comp, seq, 500, 300, status=int(protocol.Status[bit]))
    assert _want(comp) == held and comp.fault and comp.holding


def test_the_hold_bits_come_from_the_contract():
    assert tc.HOLD_BITS == int(protocol.Status.MODEL_BAD | protocol.Status.HOLD
                               | protocol.Status.CLAMP | protocol.Status.NO_DATA
                               | protocol.Status.IMPLAUSIBLE | protocol.Status.NO_REF
                               | protocol.Status.BEYOND)


def test_the_offset_never_exceeds_the_absolute_bound(tmp_path):
    text = FAST.replace("slew_nm_per_s = 10000", "slew_nm_per_s = 10000\nmax_abs_um = 1")
    comp = _comp(tmp_path, text)
    seq = _track(comp, range(0, 3001, 200), dx=-20_000)  # the box's value reaches 3 um
    assert _want(comp)["z"] == -1000 and _want(comp)["x"] == -100  # 1 um, in 10 nm counts
    comp.zero_sent()
    comp.zeroed(seq - 1)
    _line(comp, seq, 0, 2500, status=tc.REFERENCED)  # a datum change, bounded all the same
    assert _want(comp)["z"] == -1000


def test_the_default_absolute_bound_is_the_boxs_clamp():
    header = (ROOT / "firmware" / "include" / "box_config.h").read_text()
    clamp_nm = int(re.search(r"#define BOX_MAX_CORRECTION_NM (\d+)", header).group(1))
    assert tc.DEFAULT_MAX_ABS_UM * 1000 == clamp_nm


def test_a_cold_restart_holds_the_offsets_until_zero_then_carries_them(tmp_path):
    logs: list[str] = []
    comp = _comp(tmp_path, FAST, logs)
    seq = _track(comp, range(0, 3001, 200), dx=400)
    assert _want(comp) == {"z": -3000, "x": 40}
    no_ref = int(protocol.Status.NO_REF)
    # cold power-up of a start-referenced model: seq from 0, NO_REF, the box holds at 0
    for k in range(4):
        _line(comp, k, 0, 0, status=no_ref)
    assert comp.restarts == 1 and comp.await_zero and comp.holding
    comp.take_info(_info())  # INFO asked again: the same model
    for k in range(4, 40):  # however long it takes: never walks to 0
        _line(comp, k, 0, 0, status=no_ref)
    assert _want(comp) == {"z": -3000, "x": 40}
    comp.zero_sent()
    comp.zeroed(39)  # $OK,ZERO,39
    referenced = int(protocol.Status.REFERENCED)
    _line(comp, 40, 0, 0, status=referenced)  # the change since ZERO: 0
    assert _want(comp) == {"z": -3000, "x": 40} and not comp.holding
    _line(comp, 41, 30, 150, status=referenced)  # the drift goes on: held offset + change
    assert _want(comp) == {"z": -3150, "x": 43}
    assert any("until ZERO" in m for m in logs)
    del seq


def test_a_zero_before_the_restart_is_confirmed_is_the_zero_the_restart_needs(tmp_path):
    """The operator touches off right after a power cut, one line into the cold box (NO_REF,
    seq went back, not yet confirmed as a restart): that ZERO makes the held offsets the base.
    It was forgotten: the confirming line set awaiting-zero again and the offsets froze until
    a second ZERO (`make cnc`'s power cut found it)."""
    logs: list[str] = []
    comp = _comp(tmp_path, FAST, logs)
    _track(comp, range(0, 3001, 200), dx=400)
    no_ref, referenced = int(protocol.Status.NO_REF), int(protocol.Status.REFERENCED)
    _line(comp, 0, 0, 0, status=no_ref)  # the cold box's first line: suspect, held
    assert comp.suspect_seq == 0 and comp.holding
    comp.zero_sent()
    comp.zeroed(0)
    _line(comp, 1, 0, 0, status=referenced)  # confirms the restart; the change since ZERO: 0
    assert comp.restarts == 1 and not comp.await_zero
    comp.take_info(_info())
    assert _want(comp) == {"z": -3000, "x": 40}
    _line(comp, 2, 30, 150, status=referenced)  # held offset + the box's change
    assert _want(comp) == {"z": -3150, "x": 43} and not comp.holding
    assert any("zeroed before this line confirmed it" in m for m in logs)


def test_a_restart_while_the_box_reports_referenced_also_waits_for_zero(tmp_path):
    comp = _comp(tmp_path, FAST)
    _track(comp, range(0, 1001, 200))
    referenced = int(protocol.Status.REFERENCED)  # an old box zeroing at power-up
    _line(comp, 0, 0, 0, status=referenced)
    _line(comp, 1, 0, 10, status=referenced)
    comp.take_info(_info())
    _line(comp, 2, 0, 20, status=referenced)
    assert comp.await_zero and _want(comp)["z"] == -1000


def test_a_restart_that_forgets_an_operators_zero_waits_for_zero(tmp_path):
    comp = _comp(tmp_path, FAST)
    seq = _track(comp, range(0, 1001, 200))
    comp.zero_sent()
    comp.zeroed(seq - 1)
    for k in range(5):  # the new datum, then drift in it
        _line(comp, seq + k, 0, 100 * k, status=tc.REFERENCED)
    assert _want(comp)["z"] == -400
    # a model without a start reference: after a power cycle the box outputs the whole drift
    # again, unreferenced, not the drift since the operator's ZERO the offsets are in
    _line(comp, 0, 0, 900)
    _line(comp, 1, 0, 910)
    comp.take_info(_info())
    _line(comp, 2, 0, 920)
    assert comp.await_zero and _want(comp)["z"] == -400


def test_a_normal_zero_is_a_new_datum_with_base_0(tmp_path):
    comp = _comp(tmp_path, FAST)
    seq = _track(comp, range(0, 1001, 200))
    comp.zero_sent()
    comp.zeroed(seq - 1)
    _line(comp, seq, 0, 0, status=tc.REFERENCED)
    _line(comp, seq + 1, 0, 120, status=tc.REFERENCED)
    assert _want(comp)["z"] == -120 and all(a.base == 0 for a in comp.cfg.axes)


def test_an_unsolicited_zero_ack_changes_nothing(tmp_path):
    comp = _comp(tmp_path, FAST)
    seq = _track(comp, range(0, 1001, 200))
    comp.zeroed(seq - 1)  # forged $OK,ZERO: no ZERO was sent
    _line(comp, seq, 0, 0, status=tc.REFERENCED)
    assert comp.zero_acks == 0 and _want(comp)["z"] == -1000 + Z_STEP


def test_a_warm_reset_keeps_following(tmp_path):
    comp = _comp(tmp_path, FAST)
    seq = _track(comp, range(0, 1001, 200))
    wdt = int(protocol.Status.WDT_RESET | protocol.Status.REFERENCED)
    _line(comp, seq, 0, 1100, status=wdt)  # seq continues: the box kept its state
    assert comp.restarts == 0 and not comp.holding and _want(comp)["z"] == -1100


def test_the_receive_buffer_is_bounded(tmp_path):
    port = tc.Port("/dev/null", 115200)
    port.synced = True
    out: list[bytes] = []
    chunk = b"7" * 65536
    for _ in range(256):  # 16 MiB without a newline
        out += port.feed(chunk)
        assert len(port.buf) <= tc.MAX_LINE_BYTES
    assert out == [tc.OVERLONG]  # reported once, as soon as it was too long
    good = _raw(0, 0, 40)
    out = port.feed(b"123\n" + good + b"\r\n")  # the rest up to the newline is dropped
    assert out == [good]
    comp = _comp(tmp_path)
    tc.handle_line(comp, port, tc.OVERLONG, 0.0)
    assert comp.bad_lines == 1 and comp.holds == 1
    tc.handle_line(comp, port, good, 0.0)
    assert _want(comp)["z"] == -40


def test_the_frame_escape_script_counts_a_line_that_still_decodes(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("frame_escape",
                                                  ROOT / "scripts" / "frame_escape.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    row = mod.measure("bitflip", 2000, seed=1)  # CRC-16 catches 1-3 bit flips: none escape
    assert row["trials"] == 2000 and row["escape_value"] == 0
    json.dumps(row)


class _WritePort(tc.Port):
    """A port that keeps what the component writes (the box's side of the line)."""

    def __init__(self) -> None:
        super().__init__("/dev/null", 115200)
        self.written: list[bytes] = []

    def write(self, data: bytes) -> bool:
        self.written.append(data)
        return True


def test_a_zero_refused_while_holding_is_sent_again_once_the_box_no_longer_holds(tmp_path):
    comp = _comp(tmp_path, FAST)
    port = _WritePort()
    seq = _track(comp, range(0, 1001, 200))
    comp.zero_sent()
    tc.handle_line(comp, port, protocol.encode_line("E", ["HOLDING"]).rstrip(b"\r\n"), 0.0)
    assert comp.zero_deferred and comp.zero_acks == 0
    tc.handle_line(comp, port, _raw(seq, 0, 1000, status=tc.HOLD), 0.0)
    tc.handle_line(comp, port, _raw(seq + 1, 0, 1000, status=tc.SLEW), 0.0)
    assert port.written == []  # still holding, then walking back: not yet
    tc.handle_line(comp, port, _raw(seq + 2, 0, 1000), 0.0)
    assert port.written == [b"ZERO\r\n"] and comp.zero_pending and not comp.zero_deferred
    comp.zeroed(seq + 2)
    assert comp.zero_acks == 1 and comp.rezero
    tc.handle_line(comp, port, _raw(seq + 3, 0, 1000), 0.0)
    assert port.written == [b"ZERO\r\n"]  # once


def test_a_deferred_zero_waits_until_the_offsets_have_walked_to_the_box(tmp_path):
    """After a hold the box tracks again at once but the component walks its offset back at
    the step limit; a datum taken in between would keep the remaining gap."""
    comp = _comp(tmp_path, FAST)
    port = _WritePort()
    seq = _track(comp, range(0, 1001, 200))
    tc.handle_line(comp, port, _raw(seq, 0, 1000, status=tc.HOLD), 0.0)
    comp.zero_sent()
    tc.handle_line(comp, port, protocol.encode_line("E", ["HOLDING"]).rstrip(b"\r\n"), 0.0)
    big = 1000 + 3 * Z_STEP  # the box moved on while held: three steps to walk
    for k in range(1, 4):
        tc.handle_line(comp, port, _raw(seq + k, 0, big), 0.0)
        assert comp.walking == (k < 3) and port.written == ([] if k < 3 else [b"ZERO\r\n"])
    assert _want(comp)["z"] == -big


def test_a_box_without_its_datum_is_never_made_to_wait_for_zero(tmp_path):
    """After a cold power-up the box holds every axis (HOLD|NO_DATA|NO_REF) until ZERO: the
    component must not defer that ZERO waiting for the hold to end (it never would)."""
    comp = _comp(tmp_path, FAST)
    seq = _track(comp, range(0, 1001, 200))
    _line(comp, seq, 0, 0, status=tc.HOLD | tc.NO_DATA | tc.NO_REF)
    assert comp.zero_wait_reason() == ""
    _line(comp, seq + 1, 0, 0, status=tc.HOLD)
    assert comp.zero_wait_reason().startswith("box status HOLD")


# ---- probing in service: MEAS (issue 42, docs/linuxcnc.md "Probing in service") -----------
PROBE = CONF + "\n[probe]\naxis = z\ntimeout_s = 2\n"


def _reply(axis: int, seq: int, applied: bool, reason: str | None = None,
           innovation: int | None = 0, bias: int | None = 0, p: int | None = 0) -> bytes:
    return protocol.encode_meas_reply(protocol.MeasReply(
        axis, seq, applied, reason, innovation, bias, p)).rstrip(b"\r\n")


def _take(comp, raw: bytes, now: float = 0.0) -> None:
    tc.handle_line(comp, tc.Port("/dev/null", 115200), raw, now)


def test_a_probe_reading_becomes_meas_with_the_box_axis_and_the_latest_seq(tmp_path):
    comp = _comp(tmp_path, PROBE)
    _track(comp, [0, 10, 20], first_seq=40)  # seq 40..42
    # LinuxCNC 2.9's probed position contains the external offset: its change since the
    # reference touch is minus the drift's. Z sign -1: the box's displacement is -delta.
    line = comp.meas_request(-0.0345, applied_counts=-20, now=1.0)
    assert line == b"MEAS 1 34500 42\r\n"  # dz_um is the box's axis 1 (INFO order)
    assert comp.meas_pending["seq"] == 42 and not comp.meas_done
    # the same touch on a control whose probed position leaves the offset out
    comp2 = _comp(tmp_path, PROBE.replace("timeout_s = 2", "probed_includes_offset = no"))
    _track(comp2, [0], first_seq=7)
    assert comp2.meas_request(-0.0345, applied_counts=-20, now=1.0) == b"MEAS 1 34520 7\r\n"


def test_the_boxs_answer_goes_to_the_pins_and_never_moves_an_offset(tmp_path):
    comp = _comp(tmp_path, PROBE)
    seq = _track(comp, [0, 10, 20])
    before = _want(comp)
    comp.meas_request(-0.021, 0, 1.0)
    _take(comp, _reply(1, seq - 1, True, None, 1500, 1412, 235291))
    assert (comp.meas_done, comp.meas_applied, comp.meas_reason) == (True, True, "")
    z = comp.probe_axis()
    assert (z.innovation_nm, z.bias_nm, z.p_nm2) == (1500, 1412, 235291)
    assert _want(comp) == before  # the box adds the estimate to its output: nothing here
    assert comp.meas_count == 1 and comp.meas_refusals == 0
    # a chip: refused by the gate, shown, counted; the offsets stay
    comp.meas_request(0.029, 0, 2.0)
    _take(comp, _reply(1, seq - 1, False, "GATE", -49500, 1412, 235291))
    assert (comp.meas_done, comp.meas_applied, comp.meas_reason) == (True, False, "GATE")
    assert tc.MEAS_REASON_CODES["GATE"] == 1 + protocol.MEAS_REASONS.index("GATE")
    assert z.bias_nm == 1412 and z.innovation_nm == -49500 and _want(comp) == before
    comp.meas_request(0.029, 0, 3.0)
    _take(comp, _reply(1, seq - 1, False, "GATE", -49000, 1412, 235291))
    assert comp.meas_refused_in_row == 2 and comp.meas_refusals == 2
    comp.meas_request(-0.021, 0, 4.0)
    _take(comp, _reply(1, seq - 1, True, None, 100, 1500, 200000))
    assert comp.meas_refused_in_row == 0 and comp.meas_refusals == 2 and comp.meas_count == 4
    # the next sample line moves the offsets as any line does (the step limits apply)
    _line(comp, seq, 0, 30)
    assert _want(comp)["z"] == -30


@pytest.mark.parametrize("reason", protocol.MEAS_REASONS)
def test_every_refusal_of_the_box_is_shown_with_its_reason(tmp_path, reason):
    comp = _comp(tmp_path, PROBE)
    seq = _track(comp, [0])
    comp.meas_request(0.001, 0, 1.0)
    _take(comp, _reply(1, seq - 1, False, reason, None, None if reason == "AXIS" else 0,
                       None if reason == "AXIS" else 0))
    assert comp.meas_done and not comp.meas_applied and comp.meas_reason == reason
    assert tc.MEAS_REASON_CODES[reason] == 1 + protocol.MEAS_REASONS.index(reason)


def test_an_answer_to_another_reading_or_none_in_flight_is_ignored(tmp_path):
    logs: list[str] = []
    comp = _comp(tmp_path, PROBE, logs)
    seq = _track(comp, [0, 5])
    _take(comp, _reply(1, seq - 1, True, None, 7, 7, 7))  # nothing in flight (forged, late)
    assert not comp.meas_done and comp.probe_axis().bias_nm == 0
    comp.meas_request(0.001, 0, 1.0)
    _take(comp, _reply(1, seq - 2, True, None, 7, 7, 7))  # another sample
    _take(comp, _reply(0, seq - 1, True, None, 7, 7, 7))  # another axis
    assert not comp.meas_done and comp.probe_axis().bias_nm == 0
    assert sum("without that MEAS in flight" in m for m in logs) == 3


def test_no_answer_in_time_is_a_timeout_and_the_late_answer_changes_nothing(tmp_path):
    comp = _comp(tmp_path, PROBE)
    seq = _track(comp, [0])
    comp.meas_request(0.001, 0, 10.0)
    comp.check_meas_timeout(11.9)
    assert not comp.meas_done
    comp.check_meas_timeout(12.1)
    assert (comp.meas_done, comp.meas_applied, comp.meas_reason) == (True, False, "TIMEOUT")
    _take(comp, _reply(1, seq - 1, True, None, 7, 7, 7))
    assert comp.meas_reason == "TIMEOUT" and comp.probe_axis().bias_nm == 0


def test_the_component_refuses_what_it_cannot_send(tmp_path):
    comp = _comp(tmp_path, CONF)  # no [probe]
    _track(comp, [0])
    assert comp.meas_request(0.001, 0, 1.0) is None and comp.meas_reason == "NO_PROBE"
    comp = _comp(tmp_path, PROBE)  # INFO, but no sample line yet: no seq to name
    assert comp.meas_request(0.001, 0, 1.0) is None and comp.meas_reason == "LINK"
    comp = _comp(tmp_path, PROBE)
    _track(comp, [0])
    comp.take_info(_info("fedcba9876543210"))  # another model: its axis order is unknown
    assert comp.meas_request(0.001, 0, 1.0) is None and comp.meas_reason == "LINK"
    comp = _comp(tmp_path, PROBE)
    _track(comp, [0])
    assert comp.meas_request(3000.0, 0, 1.0) is None and comp.meas_reason == "RANGE"  # 3e12 nm
    assert comp.meas_done and comp.meas_refusals == 1


def test_a_parser_error_answers_the_reading_not_a_zero(tmp_path):
    comp = _comp(tmp_path, PROBE)
    _track(comp, [0])
    comp.meas_request(0.001, 0, 1.0)
    _take(comp, protocol.encode_line("E", ["BAD_ARG"]).rstrip(b"\r\n"))
    assert (comp.meas_done, comp.meas_reason) == (True, "BAD_ARG")
    comp.zero_sent()  # $E,HOLDING while a ZERO is in flight is the ZERO's
    comp.meas_request(0.001, 0, 2.0)
    _take(comp, protocol.encode_line("E", ["HOLDING"]).rstrip(b"\r\n"))
    assert comp.zero_deferred and not comp.meas_done


@pytest.mark.parametrize(("change", "needle"), [
    ("axis = z", "axis = y"),
    ("timeout_s = 2", "timeout_s = 0"),
    ("timeout_s = 2", "probed_includes_offset = maybe"),
])
def test_probe_config_errors(tmp_path, change, needle):
    path = tmp_path / "thermalcomp.conf"
    path.write_text(PROBE.replace(change, needle))
    with pytest.raises(tc.ConfigError, match=r"\[probe\]"):
        tc.load_config(path)


def test_the_shipped_config_probes_z_and_the_reason_codes_are_distinct():
    cfg = tc.load_config(ROOT / "thermal_comp" / "cnc" / "config" / "thermalcomp.conf")
    assert cfg.probe_axis == "z" and cfg.probed_includes_offset
    codes = tc.MEAS_REASON_CODES
    assert len(set(codes.values())) == len(codes) and 0 not in codes.values()
    assert set(protocol.MEAS_REASONS) <= set(codes)


def _power_cut(tmp_path, back_at: float):
    """Seq 0..4 applied one period (1 s) apart; the box's power-up's first two lines (NO_REF)
    at ``back_at`` and one period later: the second confirms the restart."""
    comp = _comp(tmp_path, FAST)
    port = _WritePort()
    for k in range(5):
        tc.handle_line(comp, port, _raw(k, 0, 200 * k), 1.0 * k)
    cold = tc.NO_REF | tc.HOLD | tc.NO_DATA
    tc.handle_line(comp, port, _raw(0, 0, 0, status=cold), back_at)
    tc.handle_line(comp, port, _raw(1, 0, 0, status=cold), back_at + 1.0)
    return comp, port


def test_after_a_power_cut_the_box_is_asked_to_resume_and_its_datum_goes_on(tmp_path):
    """A box whose backup SRAM kept its state through a power cut (battery on VBAT): the
    component asks RESUME <periods off> instead of waiting for ZERO, and follows it again."""
    comp, port = _power_cut(tmp_path, back_at=11.0)  # 7 periods after seq 4 (1 s each)
    assert comp.await_zero and port.written == [b"INFO\r\n", b"RESUME 6\r\n"]
    # the box's last seq: 4 before the cut, + 6 periods off + the 2 samples since power-up
    tc.handle_line(comp, port, tc.protocol.encode_line("OK", ["RESUME", 12]).rstrip(b"\r\n"),
                   12.0)
    assert not comp.await_zero and not comp.resume_pending
    comp.take_info(_info())  # the INFO asked after the restart
    tc.handle_line(comp, port, _raw(13, 0, 1000), 13.0)  # the old sequence goes on
    assert not comp.holding and _want(comp)["z"] == -1000 and comp.lost_lines == 0


def test_without_a_kept_state_the_box_refuses_resume_and_zero_is_awaited(tmp_path):
    comp, port = _power_cut(tmp_path, back_at=5.0)
    assert port.written[-1] == b"RESUME 0\r\n"
    tc.handle_line(comp, port, tc.protocol.encode_line("E", ["NO_STATE"]).rstrip(b"\r\n"), 6.0)
    assert comp.await_zero and not comp.resume_pending


def _ok(*fields) -> bytes:
    return protocol.encode_line("OK", list(fields)).rstrip(b"\r\n")


def _kept_then_cut(tmp_path, text: str = FAST, answer_last_snap: bool = True):
    """Seq 0..4 with a datum (REFERENCED), each answered SNAP with a 30-byte block whose
    first byte is the seq; then the box's power-up's first two lines (NO_REF)."""
    comp = _comp(tmp_path, text)
    port = _WritePort()
    for k in range(5):
        tc.handle_line(comp, port, _raw(k, 0, 200 * k, status=tc.REFERENCED), 1.0 * k)
        assert port.written[-1] == b"SNAP\r\n"
        if k < 4 or answer_last_snap:
            block = bytes([k]) + bytes(range(1, 30))
            for off in (0, 16):
                tc.handle_line(comp, port, protocol.encode(protocol.BlockPiece(
                    off, 30, block[off:off + 16])).rstrip(b"\r\n"), 1.0 * k)
            tc.handle_line(comp, port, _ok("SNAP", k), 1.0 * k)
    cold = tc.NO_REF | tc.HOLD | tc.NO_DATA
    tc.handle_line(comp, port, _raw(0, 0, 0, status=cold), 11.0)
    tc.handle_line(comp, port, _raw(1, 0, 0, status=cold), 12.0)
    return comp, port


def test_the_state_kept_by_the_controller_goes_back_before_resume(tmp_path):
    """No battery: the component kept the box's block (SNAP after each line with a datum) and
    gives it back piece by piece (each after the previous one's $OK,LOAD), then RESUME."""
    comp, port = _kept_then_cut(tmp_path)
    assert comp.keeper.kept.seq == 4 and comp.keeper.kept.block[0] == 4
    loads = protocol.encode_load(bytes([4]) + bytes(range(1, 30)))
    assert len(loads) == 2 and port.written[-1] == loads[0]  # one at a time
    tc.handle_line(comp, port, _ok("LOAD", 24), 12.1)
    assert port.written[-1] == loads[1]
    tc.handle_line(comp, port, _ok("LOAD", 30), 12.2)
    assert port.written[-1] == b"RESUME 6\r\n"  # 7 periods after seq 4, less one
    tc.handle_line(comp, port, _ok("RESUME", 12), 12.3)
    assert not comp.await_zero and not comp.resume_pending


def test_a_block_older_than_the_last_line_is_resumed_over_the_difference(tmp_path):
    """The SNAP after seq 4 was not answered before the cut: the block is seq 3's, so the box
    must also run sample 4 (RESUME n + 1)."""
    comp, port = _kept_then_cut(tmp_path, answer_last_snap=False)
    assert comp.keeper.kept.seq == 3
    tc.handle_line(comp, port, _ok("LOAD", 24), 12.1)
    tc.handle_line(comp, port, _ok("LOAD", 30), 12.2)
    assert port.written[-1] == b"RESUME 7\r\n"


def test_a_refused_load_falls_back_to_a_plain_resume(tmp_path):
    comp, port = _kept_then_cut(tmp_path)
    tc.handle_line(comp, port, protocol.encode_line("E", ["NO_RETAIN"]).rstrip(b"\r\n"), 12.1)
    assert port.written[-1] == b"RESUME 6\r\n"
    tc.handle_line(comp, port, protocol.encode_line("E", ["NO_STATE"]).rstrip(b"\r\n"), 12.2)
    assert comp.await_zero and not comp.resume_pending  # holds until ZERO, as before


def test_the_kept_state_survives_a_restart_of_the_component(tmp_path):
    text = FAST.replace("[box]", "[box]\nstate_file = box.state", 1)
    comp, _ = _kept_then_cut(tmp_path, text)
    again = _comp(tmp_path, text)
    assert again.keeper.kept.block == comp.keeper.kept.block and again.keeper.kept.seq == 4
    other = _comp(tmp_path, text.replace(HASH, "0" * len(HASH)))  # another model: not taken
    assert other.keeper.kept is None


def test_keep_state_no_sends_no_snap(tmp_path):
    comp = _comp(tmp_path, FAST.replace("[box]", "[box]\nkeep_state = no", 1))
    port = _WritePort()
    tc.handle_line(comp, port, _raw(0, 0, 0, status=tc.REFERENCED), 0.0)
    assert b"SNAP\r\n" not in port.written and comp.keeper is None
