"""contract.protocol vs docs/protocol.md: lines built here by hand (CRC from binascii) decode
to the right records, every malformation is refused with a message naming the problem."""

from __future__ import annotations

import binascii
import random
import re

import pytest

from thermal_comp.contract import protocol as p


def framed(payload: str) -> bytes:
    """A line as docs/protocol.md defines it, built without the module under test."""
    crc = binascii.crc_hqx(payload.encode(), 0xFFFF)
    return f"${payload}*{crc:04X}\r\n".encode()


def test_crc_is_ccitt_false_check_value():
    assert p.crc16(b"123456789") == 0x29B1


def test_sample_line_decodes_to_typed_fields():
    m = p.decode(framed("C,42,010C,3,1000,-250,0,2,2560,-1"))
    assert m == p.Sample(seq=42, status=0x010C, corrections_nm=(1000, -250, 0),
                         temp_codes=(2560, -1))
    assert m.flags == p.Status.WDT_RESET | p.Status.CLAMP | p.Status.SLEW
    assert p.status_names(m.status) == ["SLEW", "CLAMP", "WDT_RESET"]
    both = p.decode(framed("C,43,1800,0,0"))
    assert p.status_names(both.status) == ["REFERENCED", "IMPLAUSIBLE"]


def test_sample_with_model_bad_has_no_axes():
    m = p.decode(framed("C,0,0001,0,1,100"))
    assert m == p.Sample(0, p.Status.MODEL_BAD, (), (100,))


def test_info_line_decodes_axes_and_channel_map():
    m = p.decode(framed("I,0.1.0,0123456789abcdef,OK,1000,dx_um;dz_um,0:T01:K;1:T22:J"))
    assert m == p.Info("0.1.0", "0123456789abcdef", True, 1000, ("dx_um", "dz_um"),
                       (p.Channel(0, "T01", "K"), p.Channel(1, "T22", "J")))
    bad = p.decode(framed("I,0.1.0,0123456789abcdef,BAD,1000,,0:T01:K"))
    assert bad.crc_ok is False and bad.axes == ()


def test_status_ok_and_error_lines():
    assert p.decode(framed("S,0202,17,18,0001;0000;0200,-")) == p.StatusReport(
        0x0202, 17, 18, (p.ChannelFault.OPEN, 0, p.ChannelFault.NO_RESPONSE), None)
    assert p.decode(framed("S,0A00,17,18,0400,9")) == p.StatusReport(
        p.Status.REFERENCED | p.Status.NO_DATA, 17, 18, (p.ChannelFault.IMPLAUSIBLE,), 9)
    # a box from before ZERO ends the line after the channel faults
    old = p.decode(framed("S,0202,17,18,0001;0000;0200"))
    assert old.zero_seq is None and old.has_zero_field is False
    assert p.decode(framed("OK,RATE,60")) == p.Ack("RATE", 60)
    assert p.decode(framed("OK,ZERO,0")) == p.Ack("ZERO", 0)
    assert p.decode(framed("OK,ZERO,4294967295")) == p.Ack("ZERO", 2**32 - 1)
    for reason in ("UNKNOWN", "TOO_LONG", "BINARY", "BAD_ARG"):
        assert p.decode(framed(f"E,{reason}")) == p.ErrorReply(reason)


def test_line_without_crlf_and_as_str_is_accepted():
    raw = framed("E,UNKNOWN")
    assert p.decode(raw.rstrip(b"\r\n")) == p.decode(raw.decode()) == p.ErrorReply("UNKNOWN")


def test_every_single_bit_flip_is_detected():
    raw = framed("C,7,0000,3,12345,-6789,0,4,2560,2561,2562,-300").rstrip(b"\r\n")
    for i in range(len(raw) * 8):
        corrupt = bytearray(raw)
        corrupt[i // 8] ^= 1 << (i % 8)
        with pytest.raises(p.ProtocolError):
            p.decode(bytes(corrupt))


@pytest.mark.parametrize(("payload", "needle"), [
    ("C,1,0000,2,5,1", "missing field 6 (n_ch)"),  # n_axes says 2: n_ch is missing
    ("C,1,0000,1,5,1,7,8", "unexpected field"),   # more codes than n_ch
    ("C,1,000G,0,0", "status"),                   # not hex
    ("C,1,10c,0,0", "status"),                    # not 4 upper-case digits
    ("C,-1,0000,0,0", "seq"),                     # negative seq
    ("C,1,0000,0,1,262144", "temp_code[0]"),      # outside 19 bits
    ("C,1,0000,1,2147483648,0", "corr_nm[0]"),    # outside int32
    ("C,01,0000,0,0", "seq"),                     # leading zero is not how the box writes
    ("I,0.1.0,abc,MAYBE,1000,,", "crc"),
    ("I,0.1.0,abc,OK,1000,,0:T01:X", "channel map"),
    ("S,0000,1,2,01", "channel fault"),
    ("OK,RATE,0", "RATE"),
    ("OK,RATE,3601", "RATE"),
    ("OK,INFO,1", "RATE"),
    ("OK,ZERO,-1", "seq"),
    ("OK,ZERO", "missing field"),
    ("S,0000,1,2,0001,x", "zero_seq"),
    ("S,0000,1,2,0001,-,0:-:0,3", "unexpected field"),
    ("S,0000,1,2,0001,-,3", "service entry"),
    ("S,0000,1,2,0001,-,1:2", "service entry"),
    ("M,0,5,A,GATE,1,2,3", "applied reading"),
    ("M,0,5,R,CHIP,1,2,3", "reason"),
    ("M,0,5,X,-,1,2,3", "verdict"),
    ("M,0,5,A,-,-,2,3", "applied reading without"),
    ("M,0,5,R,SEQ,-,2,-3", "p_nm2"),
    ("E,NOPE", "reason"),
    ("X,1", "unknown line type"),
])
def test_malformed_fields_name_the_problem(payload, needle):
    with pytest.raises(p.ProtocolError, match=re.escape(needle)) as info:
        p.decode(framed(payload))
    assert payload[:10] in str(info.value)  # the line is quoted


@pytest.mark.parametrize(("raw", "needle"), [
    (b"C,1,0000,0,0*1234", "start with '\\$'"),
    (b"$C,1,0000,0,0", "'\\*' and 4 upper-case hex"),
    (b"$C,1,0000,0,0*12ab", "'\\*' and 4 upper-case hex"),
    (b"$C,1,\xff,0,0*1234", "printable ASCII"),
    ("$C,1,0000,0,0*ÄÄÄÄ", "non-ASCII"),
])
def test_broken_framing_is_refused(raw, needle):
    with pytest.raises(p.ProtocolError, match=needle):
        p.decode(raw)


def test_crc_mismatch_is_its_own_error_type():
    raw = bytearray(framed("E,BINARY"))
    raw[-3] = ord("0") if raw[-3] != ord("0") else ord("1")
    with pytest.raises(p.CrcError, match="CRC mismatch"):
        p.decode(bytes(raw))


def test_encoders_round_trip_random_records():
    rng = random.Random(5)
    for _ in range(200):
        n_axes, n_ch = rng.randint(0, 6), rng.randint(1, 8)
        sample = p.Sample(rng.randrange(2**32), rng.randrange(2**10),
                          tuple(rng.randint(-(2**31), 2**31 - 1) for _ in range(n_axes)),
                          tuple(rng.randint(-(2**18), 2**18 - 1) for _ in range(n_ch)))
        assert p.decode(p.encode(sample)) == sample
    info = p.Info("1.2.3", "ffffffffffffffff", False, 250, ("dz_um",), (p.Channel(3, "T3", "J"),))
    report = p.StatusReport(0x3FF, 2**32 - 1, 86400, (0x200, 0x1FF))
    zeroed = p.StatusReport(0x1800, 5, 6, (0x400,), 2**32 - 1)
    old = p.StatusReport(0x0000, 5, 6, (0,), None, has_zero_field=False)
    for message in (info, report, zeroed, old, p.Ack("RATE", 3600), p.Ack("ZERO", 77),
                    p.ErrorReply("TOO_LONG")):
        assert p.decode(p.encode(message)) == message


def test_encoded_sample_is_byte_identical_to_a_hand_built_line():
    assert p.encode_sample(3, 0x0202, [-5, 6], [7]) == framed("C,3,0202,2,-5,6,1,7")


def test_commands_are_encoded_and_checked():
    assert p.encode_command("INFO") == b"INFO\r\n"
    assert p.encode_command("RATE", 10) == b"RATE 10\r\n"
    assert p.encode_command("ZERO") == b"ZERO\r\n"
    with pytest.raises(ValueError, match="RATE 0 outside"):
        p.encode_command("RATE", 0)
    with pytest.raises(ValueError, match="unknown command"):
        p.encode_command("RESET")


def test_meas_reply_and_status_service_field_round_trip():
    """issue 42: $M answers MEAS; STATUS carries per axis bias:innovation:refusals."""
    applied = p.MeasReply(0, 17, True, None, 5000, 4706, 235291)
    refused = p.MeasReply(1, 18, False, "GATE", 45294, 4706, 235391)
    early = p.MeasReply(7, 18, False, "AXIS", None, None, None)
    for m in (applied, refused, early):
        assert p.decode(p.encode(m)) == m
    assert p.encode(applied) == framed("M,0,17,A,-,5000,4706,235291")
    assert p.decode(framed("M,2,3,R,OFF,-,-,-")) == p.MeasReply(2, 3, False, "OFF", None,
                                                                 None, None)
    status = p.decode(framed("S,0800,9,1,0000,0,4706:5000:0;0:-:2;-"))
    assert status.service == (p.AxisService(4706, 5000, 0), p.AxisService(0, None, 2), None)
    assert p.decode(p.encode(status)) == status
    # a box from before MEAS: no service field
    assert p.decode(framed("S,0800,9,1,0000,0")).service is None
    # the gate's lock-out ended (docs/service.md, "Re-opening"): applied, reason REOPEN, and
    # STATUS counts the re-openings in a fourth part
    reopened = p.MeasReply(2, 180, True, "REOPEN", 60016, 60016, 340)
    assert p.decode(p.encode(reopened)) == reopened
    assert p.encode(reopened) == framed("M,2,180,A,REOPEN,60016,60016,340")
    status = p.decode(framed("S,0800,9,1,0000,0,4706:5000:0:0;60016:60016:0:1;-"))
    assert status.service == (p.AxisService(4706, 5000, 0, 0), p.AxisService(60016, 60016, 0, 1),
                              None)
    assert p.decode(p.encode(status)) == status
    assert p.encode_meas(1, -2500, 42) == b"MEAS 1 -2500 42\r\n"
    with pytest.raises(p.InputError):
        p.encode_meas(0, 2**31, 1)
