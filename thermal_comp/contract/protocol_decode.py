"""Decoding the box's lines, strictly: a field of the wrong form is refused, naming the field.

A half-understood line could move a machine axis, so a line is accepted only if its CRC matches
*and* every field has the declared form; the message quotes the line.
"""

from __future__ import annotations

import re

from thermal_comp.contract.model_checker import NAME_CHARS
from thermal_comp.contract.protocol_frame import LINE_RE, crc16
from thermal_comp.contract.protocol_messages import (
    BLOCK_LINE_BYTES,
    ERROR_REASONS,
    LOAD_MAX_BYTES,
    LOAD_OFFSET_MAX,
    MEAS_REASONS,
    RATE_MAX,
    RATE_MIN,
    TC_TYPES,
    Ack,
    AxisService,
    BlockPiece,
    Channel,
    CrcError,
    ErrorReply,
    Info,
    MeasReply,
    Message,
    ProtocolError,
    Sample,
    StatusReport,
)

_DEC_RE = re.compile(r"-?(0|[1-9][0-9]*)")
_UDEC_RE = re.compile(r"0|[1-9][0-9]*")
_HEX4_RE = re.compile(r"[0-9A-F]{4}")
_NAME_RE = re.compile(rf"[{NAME_CHARS}]*")  # a model's names (contract.model_checker)
_HEX_BYTES_RE = re.compile(r"(?:[0-9A-F]{2})+")


def _show(raw: bytes) -> str:
    text = repr(raw[:120])
    return text + ("..." if len(raw) > 120 else "")


class _Fields:
    """Cursor over a line's comma-separated fields, producing errors that name the field."""

    def __init__(self, kind: str, fields: list[str], raw: bytes) -> None:
        self.kind, self.fields, self.raw, self.pos = kind, fields, raw, 0

    def fail(self, what: str) -> ProtocolError:
        return ProtocolError(f"${self.kind} line, field {self.pos + 1}: {what}: {_show(self.raw)}")

    def take(self, name: str) -> str:
        if self.pos >= len(self.fields):
            raise ProtocolError(f"${self.kind} line: missing field {self.pos + 1} ({name}): "
                                f"{_show(self.raw)}")
        self.pos += 1
        return self.fields[self.pos - 1]

    def _match(self, name: str, regex: re.Pattern[str], form: str) -> str:
        text = self.take(name)
        if not regex.fullmatch(text):
            self.pos -= 1
            raise self.fail(f"{name} {text!r} is not {form}")
        return text

    def dec(self, name: str, lo: int | None = None, hi: int | None = None) -> int:
        value = int(self._match(name, _DEC_RE, "a decimal integer"))
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            self.pos -= 1
            raise self.fail(f"{name} {value} outside {lo}..{hi}")
        return value

    def udec(self, name: str, hi: int | None = None, lo: int = 0) -> int:
        value = int(self._match(name, _UDEC_RE, "an unsigned decimal integer"))
        if value < lo or (hi is not None and value > hi):
            self.pos -= 1
            raise self.fail(f"{name} {value} outside {lo}..{hi if hi is not None else ''}")
        return value

    def hex4(self, name: str) -> int:
        return int(self._match(name, _HEX4_RE, "4 upper-case hex digits"), 16)

    def name_list(self, name: str) -> list[str]:
        text = self.take(name)
        return [] if text == "" else text.split(";")

    def end(self) -> None:
        if self.pos != len(self.fields):
            raise ProtocolError(f"${self.kind} line: {len(self.fields) - self.pos} unexpected "
                                f"field(s) after field {self.pos}: {_show(self.raw)}")


def _decode_sample(f: _Fields) -> Sample:
    seq = f.udec("seq", 2**32 - 1)
    status = f.hex4("status")
    n_axes = f.udec("n_axes", 32)
    corr = tuple(f.dec(f"corr_nm[{a}]", -(2**31), 2**31 - 1) for a in range(n_axes))
    n_ch = f.udec("n_ch", 32)
    codes = tuple(f.dec(f"temp_code[{c}]", -(2**18), 2**18 - 1) for c in range(n_ch))
    f.end()
    return Sample(seq, status, corr, codes)


def _decode_info(f: _Fields) -> Info:
    fw = f.take("fw_version")
    model_hash = f.take("model_hash")
    crc = f.take("crc")
    if crc not in ("OK", "BAD"):
        f.pos -= 1
        raise f.fail(f"crc {crc!r} is neither OK nor BAD")
    period = f.udec("period_ms")
    axes = f.name_list("axes")
    channels = []
    for item in f.name_list("channel map"):
        parts = item.split(":")
        if (len(parts) != 3 or not _UDEC_RE.fullmatch(parts[0])
                or not _NAME_RE.fullmatch(parts[1]) or parts[2] not in TC_TYPES):
            f.pos -= 1
            raise f.fail(f"channel map entry {item!r} is not <ch>:<sensor>:<K|J>")
        channels.append(Channel(int(parts[0]), parts[1], parts[2]))
    f.end()
    return Info(fw, model_hash, crc == "OK", period, tuple(axes), tuple(channels))


def _decode_status(f: _Fields) -> StatusReport:
    status = f.hex4("status")
    seq = f.udec("seq", 2**32 - 1)
    uptime = f.udec("uptime_s")
    faults = []
    for item in f.name_list("channel faults"):
        if not _HEX4_RE.fullmatch(item):
            f.pos -= 1
            raise f.fail(f"channel fault word {item!r} is not 4 upper-case hex digits")
        faults.append(int(item, 16))
    if f.pos == len(f.fields):  # firmware before ZERO: no zero_seq field
        return StatusReport(status, seq, uptime, tuple(faults), None, has_zero_field=False)
    zero_seq = None
    if f.fields[f.pos] == "-":
        f.take("zero_seq")
    else:
        zero_seq = f.udec("zero_seq", 2**32 - 1)
    service = None
    if f.pos < len(f.fields):  # firmware with MEAS: the estimator per axis
        service = tuple(_axis_service(f, item) for item in f.name_list("service"))
    f.end()
    return StatusReport(status, seq, uptime, tuple(faults), zero_seq, service=service)


def _axis_service(f: _Fields, item: str) -> AxisService | None:
    """``<bias_nm>:<innovation_nm or ->:<refusals>[:<reopens>]``, or ``-`` (no estimator)."""
    if item == "-":
        return None
    parts = item.split(":")
    if (len(parts) not in (3, 4) or not _DEC_RE.fullmatch(parts[0])
            or not (parts[1] == "-" or _DEC_RE.fullmatch(parts[1]))
            or not all(_UDEC_RE.fullmatch(x) and int(x) <= 65535 for x in parts[2:])
            or not all(-(2**31) <= int(x) < 2**31 for x in parts[:2] if x != "-")):
        f.pos -= 1
        raise f.fail(f"service entry {item!r} is not <bias_nm>:<innovation_nm|->:<refusals>"
                     "[:<reopens>] or -")
    return AxisService(int(parts[0]), None if parts[1] == "-" else int(parts[1]),
                       int(parts[2]), int(parts[3]) if len(parts) == 4 else None)


def _decode_meas(f: _Fields) -> MeasReply:
    axis = f.udec("axis", 2**32 - 1)
    seq = f.udec("seq", 2**32 - 1)
    verdict = f.take("verdict")
    if verdict not in ("A", "R"):
        f.pos -= 1
        raise f.fail(f"verdict {verdict!r} is neither A nor R")
    reason_text = f.take("reason")
    reasons = ("-", "REOPEN") if verdict == "A" else MEAS_REASONS  # REOPEN: lock-out ended
    if reason_text not in reasons:
        f.pos -= 1
        raise f.fail(f"{'an applied reading: ' * (verdict == 'A')}reason {reason_text!r} is "
                     f"not one of {', '.join(reasons)}")
    values: list[int | None] = []
    for name in ("innovation_nm", "bias_nm", "p_nm2"):
        if f.pos < len(f.fields) and f.fields[f.pos] == "-":
            f.take(name)
            values.append(None)
        elif name == "p_nm2":
            values.append(f.udec(name, 2**32 - 1))
        else:
            values.append(f.dec(name, -(2**31), 2**31 - 1))
    f.end()
    if verdict == "A" and None in values:
        raise ProtocolError(f"$M line: an applied reading without innovation, bias or "
                            f"variance: {_show(f.raw)}")
    return MeasReply(axis, seq, verdict == "A", None if reason_text == "-" else reason_text,
                     *values)


def _decode_ok(f: _Fields) -> Ack:
    command = f.take("command")
    if command == "RATE":
        value = f.udec("n", RATE_MAX, RATE_MIN)
    elif command in ("ZERO", "RESUME", "SNAP"):
        value = f.udec("seq", 2**32 - 1)
    elif command == "LOAD":
        value = f.udec("end", LOAD_OFFSET_MAX + LOAD_MAX_BYTES)
    else:
        f.pos -= 1
        raise f.fail(f"acknowledged command {command!r} is none of RATE, ZERO, RESUME, SNAP, "
                     "LOAD")
    f.end()
    return Ack(command, value)


def _decode_error(f: _Fields) -> ErrorReply:
    reason = f.take("reason")
    if reason not in ERROR_REASONS:
        f.pos -= 1
        raise f.fail(f"reason {reason!r} is not one of {', '.join(ERROR_REASONS)}")
    f.end()
    return ErrorReply(reason)


def _decode_block(f: _Fields) -> BlockPiece:
    offset = f.udec("offset", LOAD_OFFSET_MAX)
    size = f.udec("size", LOAD_OFFSET_MAX + 1, 1)
    data = bytes.fromhex(f._match("data", _HEX_BYTES_RE, "upper-case hex bytes"))
    f.end()
    if len(data) > BLOCK_LINE_BYTES or offset + len(data) > size:
        raise ProtocolError(f"$B line: {len(data)} bytes at {offset} do not fit a piece of at "
                            f"most {BLOCK_LINE_BYTES} bytes of a {size}-byte block: "
                            f"{_show(f.raw)}")
    return BlockPiece(offset, size, data)


_DECODERS = {"C": _decode_sample, "I": _decode_info, "S": _decode_status, "OK": _decode_ok,
             "E": _decode_error, "M": _decode_meas, "B": _decode_block}


def decode(raw: bytes | str) -> Message:
    """Decode one line (with or without its ``\\r\\n``) into a typed record.

    Raises :class:`CrcError` when the check fails and :class:`ProtocolError` for any other
    malformation (the message names the field and quotes the line).
    """
    if isinstance(raw, str):
        try:
            raw = raw.encode("ascii")
        except UnicodeEncodeError:
            raise ProtocolError(f"line contains non-ASCII characters: {raw[:120]!r}") from None
    m = LINE_RE.fullmatch(raw)
    if m is None:
        if not raw.startswith(b"$"):
            raise ProtocolError(f"line does not start with '$': {_show(raw)}")
        if any(b < 0x20 or b > 0x7E for b in raw.rstrip(b"\r\n")):
            raise ProtocolError(f"line contains bytes outside printable ASCII: {_show(raw)}")
        raise ProtocolError(f"line does not end in '*' and 4 upper-case hex digits: {_show(raw)}")
    payload, crc_text = m.group(1), m.group(2)
    expected = crc16(payload)
    if int(crc_text, 16) != expected:
        raise CrcError(f"CRC mismatch (line says {crc_text.decode()}, payload gives "
                       f"{expected:04X}): {_show(raw)}")
    kind, *fields = payload.decode("ascii").split(",")
    decoder = _DECODERS.get(kind)
    if decoder is None:
        raise ProtocolError(f"unknown line type {kind!r} (known: {', '.join(_DECODERS)}): "
                            f"{_show(raw)}")
    return decoder(_Fields(kind, fields, raw))


parse_line = decode
