"""The box's serial wire protocol (docs/protocol.md): decode its lines, encode commands.

One decoder shared by the HIL runner and ``host monitor``, so both judge the box by the same
rules. Decoding is strict: a line is accepted only if its CRC-16/CCITT-FALSE matches *and*
every field has the declared form; anything else raises :class:`ProtocolError` naming the
field and quoting the line, because a half-understood line could move a machine axis.
The encoders (``encode_*``) build lines exactly as the firmware does; tests use them to check
the decoder independently of the firmware, and the firmware against the decoder.
"""

from __future__ import annotations

import binascii
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import IntFlag

from thermal_comp.contract.errors import InputError

CMD_MAX_LEN = 64
RATE_MIN, RATE_MAX = 1, 3600
# HOLDING: ZERO refused (an axis holds or walks); NO_STATE: RESUME refused (no retained state
# of this model kept through the power cut), or SNAP before the box has a state to give;
# IN_USE: LOAD refused (a datum is in force, or the model has no start reference);
# NO_RETAIN: LOAD refused (the board has no retained memory to load into)
ERROR_REASONS = ("UNKNOWN", "TOO_LONG", "BINARY", "BAD_ARG", "HOLDING", "NO_STATE", "IN_USE",
                 "NO_RETAIN")
RESUME_MAX = 65535  # RESUME <n>: sample periods the box was off (CMD_RESUME_MAX in cmd.h)
# SNAP / LOAD (docs/protocol.md, "State kept by the controller"): the box's state block, sent
# in $B pieces of at most BLOCK_LINE_BYTES bytes and put back in LOAD pieces of at most
# LOAD_MAX_BYTES (CMD_LOAD_MAX_BYTES in cmd.h) at offsets up to LOAD_OFFSET_MAX
BLOCK_LINE_BYTES = 256
LOAD_MAX_BYTES = 24
LOAD_OFFSET_MAX = 65535
TC_TYPES = ("K", "J")
# MEAS <axis> <nm> <seq> (issue 42, docs/service.md): a probe reading. The box answers $M,
# applied (A) or refused (R) with one of these reasons, in the order the box checks them:
#   OFF      the model has no service block for the axis (or its tables failed their CRC)
#   AXIS     no such axis (index >= the INFO line's axis count)
#   NO_REF   no reference: a start model before its ZERO, a ZERO pending, or the reference
#            of the sample still being averaged (the first BOX_ZERO_SAMPLES after ZERO)
#   SEQ      a sample the box does not remember (older than MEAS_SAMPLES, from before the
#            latest ZERO or warm reset, or not produced yet)
#   HOLDING  the axis held or walked back at that sample, or does at the latest one
#   GATE     the innovation is beyond the gate of the model's own uncertainty
MEAS_REASONS = ("OFF", "AXIS", "NO_REF", "SEQ", "HOLDING", "GATE")
MEAS_SAMPLES = 4  # samples per axis the box remembers for MEAS (BOX_MEAS_SAMPLES)
MEAS_NM_MIN, MEAS_NM_MAX = -(2**31), 2**31 - 1


class Status(IntFlag):
    """The status word of sample and STATUS lines."""

    MODEL_BAD = 1 << 0
    HOLD = 1 << 1
    SLEW = 1 << 2
    CLAMP = 1 << 3
    RANGE = 1 << 4
    OPEN = 1 << 5
    TC_FAULT = 1 << 6
    AUX_FAULT = 1 << 7
    WDT_RESET = 1 << 8
    NO_DATA = 1 << 9
    EXTRAP = 1 << 10  # a valid reading beyond its training window: advice, still corrected
    REFERENCED = 1 << 11  # a ZERO reference is in force: corrections are the change since it
    IMPLAUSIBLE = 1 << 12  # a reading changed faster than its channel can: the model held it
    NO_REF = 1 << 13  # a start-referenced model after a cold power-up: every axis holds until ZERO
    BEYOND = 1 << 14  # a reading beyond what training supports (runaway/stuck): its axes hold


STATUS_BITS = tuple(s.name for s in Status)  # bit order: STATUS_BITS[i] is bit i


class ChannelFault(IntFlag):
    """Per-channel fault word of the STATUS line: the MAX31856 SR bits, then the box's own."""

    OPEN = 0x01
    OVUV = 0x02
    TCLOW = 0x04
    TCHIGH = 0x08
    CJLOW = 0x10
    CJHIGH = 0x20
    TCRANGE = 0x40
    CJRANGE = 0x80
    RANGE = 1 << 8  # code outside the channel's valid range
    NO_RESPONSE = 1 << 9  # bus error or the chip did not read its configuration back
    IMPLAUSIBLE = 1 << 10  # the plausibility guard rejected the reading (held or faulted)
    BEYOND = 1 << 11  # beyond the trained range plus its margin: a channel fault, axes hold
    STUCK = 1 << 12  # the same code max_still_samples times in a row: a channel fault, axes hold


class ProtocolError(InputError):
    """A line that is not a valid protocol line; the message says what and quotes the line."""


class CrcError(ProtocolError):
    """The line's CRC does not match its payload (corrupted in transit)."""


def status_names(status: int) -> list[str]:
    """Names of the bits set in a status word, in bit order."""
    return [name for i, name in enumerate(STATUS_BITS) if status >> i & 1]


@dataclass(frozen=True)
class Channel:
    """One entry of the INFO channel map."""

    channel: int
    sensor: str
    tc_type: str


@dataclass(frozen=True)
class Info:
    """``$I``: firmware and model identity."""

    fw_version: str
    model_hash: str
    crc_ok: bool
    period_ms: int
    axes: tuple[str, ...]
    channels: tuple[Channel, ...]


@dataclass(frozen=True)
class Sample:
    """``$C``: one sample period's output."""

    seq: int
    status: int
    corrections_nm: tuple[int, ...]
    temp_codes: tuple[int, ...]

    @property
    def flags(self) -> Status:
        return Status(self.status)


@dataclass(frozen=True)
class AxisService:
    """One axis of the STATUS line's service field: the in-service estimate (the bias added
    to the model's output, nm), the last reading's innovation (nm; None: none since the last
    reset or ZERO), the readings the gate refused in a row since the last accepted one and
    the re-openings (REOPEN) since then, both up to 65535 (reopens None: an older box)."""

    bias_nm: int
    innovation_nm: int | None
    refusals: int
    reopens: int | None = None


@dataclass(frozen=True)
class StatusReport:
    """``$S``: answer to STATUS.

    ``zero_seq``: seq of the first sample of the ZERO reference in force, None when there is
    none (the box sends ``-``) or when the box predates ZERO (no such field).
    ``service``: per axis the estimator's state (None for an axis without a service block:
    MEAS is OFF); None as a whole when the box predates MEAS (no such field).
    """

    status: int
    seq: int
    uptime_s: int
    channel_faults: tuple[int, ...]
    zero_seq: int | None = None
    has_zero_field: bool = True  # False: a box from before ZERO (the line ends after faults)
    service: tuple[AxisService | None, ...] | None = None


@dataclass(frozen=True)
class MeasReply:
    """``$M``: the answer to ``MEAS <axis> <nm> <seq>``.

    ``applied``: the reading moved the estimate (its effect reaches the output from the next
    sample on, through the step limit; reason None, or REOPEN); else one of MEAS_REASONS.
    ``innovation_nm``: reading - (model + bias) at that sample (None when the box refused
    before computing it); ``bias_nm`` / ``p_nm2``: the estimate and its variance afterwards
    (nm, nm^2; None for AXIS)."""

    axis: int
    seq: int
    applied: bool
    reason: str | None
    innovation_nm: int | None
    bias_nm: int | None
    p_nm2: int | None


@dataclass(frozen=True)
class BlockPiece:
    """``$B,<offset>,<size>,<hex>``: a piece of the state block the box keeps (its answer to
    ``SNAP``, before ``$OK,SNAP,<seq>``). Opaque to the controller: it keeps the pieces and
    gives them back with LOAD; the box checks the block (magic, model CRC, CRC-32)."""

    offset: int
    size: int
    data: bytes


@dataclass(frozen=True)
class Ack:
    """``$OK``: a command was accepted: ``$OK,RATE,<n>``; ``$OK,ZERO,<seq>``,
    ``$OK,RESUME,<seq>`` or ``$OK,SNAP,<seq>`` with the seq of the latest sample (0 before the
    first); ``$OK,LOAD,<end>`` with the offset just past the piece written."""

    command: str
    value: int


@dataclass(frozen=True)
class ErrorReply:
    """``$E``: a command was refused."""

    reason: str


Message = Info | Sample | StatusReport | Ack | ErrorReply | MeasReply | BlockPiece

_LINE_RE = re.compile(rb"\$([\x20-\x7e]*)\*([0-9A-F]{4})(\r?\n)?")
_DEC_RE = re.compile(r"-?(0|[1-9][0-9]*)")
_UDEC_RE = re.compile(r"0|[1-9][0-9]*")
_HEX4_RE = re.compile(r"[0-9A-F]{4}")
_NAME_RE = re.compile(r"[A-Za-z0-9_.+-]*")
_HEX_BYTES_RE = re.compile(r"(?:[0-9A-F]{2})+")


def crc16(payload: bytes) -> int:
    """CRC-16/CCITT-FALSE of the bytes between ``$`` and ``*``."""
    return binascii.crc_hqx(payload, 0xFFFF)


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
    m = _LINE_RE.fullmatch(raw)
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


# ---- encoders ---------------------------------------------------------------------------

def encode_line(kind: str, fields: Iterable[object]) -> bytes:
    """``$<kind>,<fields...>*<CRC>\\r\\n`` exactly as the box writes it."""
    payload = ",".join([kind, *(str(f) for f in fields)]).encode("ascii")
    return b"$" + payload + b"*" + f"{crc16(payload):04X}".encode() + b"\r\n"


def encode_sample(seq: int, status: int, corrections_nm: Sequence[int],
                  temp_codes: Sequence[int]) -> bytes:
    return encode_line("C", [seq, f"{status:04X}", len(corrections_nm), *corrections_nm,
                             len(temp_codes), *temp_codes])


def encode_info(info: Info) -> bytes:
    channels = ";".join(f"{c.channel}:{c.sensor}:{c.tc_type}" for c in info.channels)
    return encode_line("I", [info.fw_version, info.model_hash, "OK" if info.crc_ok else "BAD",
                             info.period_ms, ";".join(info.axes), channels])


def encode_status(report: StatusReport) -> bytes:
    faults = ";".join(f"{w:04X}" for w in report.channel_faults)
    fields: list[object] = [f"{report.status:04X}", report.seq, report.uptime_s, faults]
    if report.has_zero_field:
        fields.append("-" if report.zero_seq is None else report.zero_seq)
        if report.service is not None:
            fields.append(";".join("-" if a is None else
                                   f"{a.bias_nm}:{_dash(a.innovation_nm)}:{a.refusals}"
                                   + ("" if a.reopens is None else f":{a.reopens}")
                                   for a in report.service))
    return encode_line("S", fields)


def _dash(value: int | None) -> str:
    return "-" if value is None else str(value)


def encode_meas_reply(reply: MeasReply) -> bytes:
    return encode_line("M", [reply.axis, reply.seq, "A" if reply.applied else "R",
                             reply.reason or "-", _dash(reply.innovation_nm),
                             _dash(reply.bias_nm), _dash(reply.p_nm2)])


def encode(message: Message) -> bytes:
    """Encode any decoded record back into its line (decode(encode(m)) == m)."""
    if isinstance(message, Sample):
        return encode_sample(message.seq, message.status, message.corrections_nm,
                             message.temp_codes)
    if isinstance(message, Info):
        return encode_info(message)
    if isinstance(message, StatusReport):
        return encode_status(message)
    if isinstance(message, Ack):
        return encode_line("OK", [message.command, message.value])
    if isinstance(message, ErrorReply):
        return encode_line("E", [message.reason])
    if isinstance(message, MeasReply):
        return encode_meas_reply(message)
    if isinstance(message, BlockPiece):
        return encode_line("B", [message.offset, message.size, message.data.hex().upper()])
    raise TypeError(f"not a protocol message: {message!r}")


def encode_command(command: str, arg: int | None = None) -> bytes:
    """A command line for the box: ``INFO``, ``STATUS``, ``ZERO``, ``SNAP``, ``RATE <n>`` or
    ``RESUME <n>``, CR LF terminated (``LOAD``: encode_load)."""
    if command in ("INFO", "STATUS", "ZERO", "SNAP") and arg is None:
        return command.encode() + b"\r\n"
    if command == "RATE" and arg is not None:
        if not RATE_MIN <= arg <= RATE_MAX:
            raise InputError(f"RATE {arg} outside {RATE_MIN}..{RATE_MAX}")
        return f"RATE {arg}\r\n".encode()
    if command == "RESUME" and arg is not None:
        if not 0 <= arg <= RESUME_MAX:
            raise InputError(f"RESUME {arg} outside 0..{RESUME_MAX}")
        return f"RESUME {arg}\r\n".encode()
    raise InputError(f"unknown command {command!r} (INFO, STATUS, ZERO, SNAP, RATE <n>, "
                     "RESUME <n>, or MEAS: encode_meas, LOAD: encode_load)")


def encode_load(block: bytes) -> list[bytes]:
    """The ``LOAD <offset> <hex>`` lines that give ``block`` (a state block SNAP sent, put
    together) back to the box, in order; send each after the previous one's ``$OK,LOAD``."""
    if not 0 < len(block) <= LOAD_OFFSET_MAX + 1:
        raise InputError(f"a state block of {len(block)} bytes: 1..{LOAD_OFFSET_MAX + 1}")
    return [f"LOAD {off} {block[off:off + LOAD_MAX_BYTES].hex().upper()}\r\n".encode()
            for off in range(0, len(block), LOAD_MAX_BYTES)]


def assemble_block(pieces: Sequence[BlockPiece]) -> bytes:
    """The block SNAP sent, from its ``$B`` pieces in order; InputError if they do not make
    one whole block (a piece lost, repeated or of another size)."""
    if not pieces:
        raise InputError("no $B piece: the box sent no state block")
    size, out = pieces[0].size, bytearray()
    for p in pieces:
        if p.size != size or p.offset != len(out):
            raise InputError(f"$B piece at {p.offset} (block of {p.size} bytes) after "
                             f"{len(out)} bytes of a {size}-byte block: pieces lost or mixed")
        out += p.data
    if len(out) != size:
        raise InputError(f"state block: {len(out)} of {size} bytes")
    return bytes(out)


def encode_meas(axis: int, nm: int, seq: int) -> bytes:
    """``MEAS <axis> <nm> <seq>``: a probe reading of axis ``axis`` (0-based, INFO order),
    the displacement since the reference in nm, of the sample ``seq``."""
    if not 0 <= axis < 2**32 or not MEAS_NM_MIN <= nm <= MEAS_NM_MAX or not 0 <= seq < 2**32:
        raise InputError(f"MEAS {axis} {nm} {seq}: axis and seq are uint32, nm int32")
    return f"MEAS {axis} {nm} {seq}\r\n".encode()
