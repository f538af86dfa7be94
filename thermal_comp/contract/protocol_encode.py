"""Encoding lines and commands exactly as the box and its controller write them.

Tests use the encoders to check the decoder independently of the firmware, and the firmware
against the decoder; the controller side sends its commands with them.
"""

from __future__ import annotations

from collections.abc import Sequence

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.protocol_frame import encode_line
from thermal_comp.contract.protocol_messages import (
    LOAD_MAX_BYTES,
    LOAD_OFFSET_MAX,
    MEAS_NM_MAX,
    MEAS_NM_MIN,
    RATE_MAX,
    RATE_MIN,
    RESUME_MAX,
    Ack,
    BlockPiece,
    ErrorReply,
    Info,
    MeasReply,
    Message,
    Sample,
    StatusReport,
)


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
