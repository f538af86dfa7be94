"""The box's serial wire protocol (docs/protocol.md): decode its lines, encode commands.

One decoder shared by the HIL runner and ``host monitor``, so both judge the box by the same
rules. Decoding is strict: a line is accepted only if its CRC-16/CCITT-FALSE matches *and*
every field has the declared form; anything else raises :class:`ProtocolError` naming the
field and quoting the line, because a half-understood line could move a machine axis.
The encoders (``encode_*``) build lines exactly as the firmware does; tests use them to check
the decoder independently of the firmware, and the firmware against the decoder.

Every caller imports the protocol from here; its parts live by job: the words and records
(``protocol_messages``), the frame and its CRC (``protocol_frame``), the decoder
(``protocol_decode``), the encoders (``protocol_encode``).
"""

from __future__ import annotations

from thermal_comp.contract.errors import InputError
from thermal_comp.contract.protocol_decode import (
    decode,
    parse_line,
)
from thermal_comp.contract.protocol_encode import (
    assemble_block,
    encode,
    encode_command,
    encode_info,
    encode_load,
    encode_meas,
    encode_meas_reply,
    encode_sample,
    encode_status,
)
from thermal_comp.contract.protocol_frame import (
    LINE_RE,
    crc16,
    encode_line,
)
from thermal_comp.contract.protocol_messages import (
    BLOCK_LINE_BYTES,
    CMD_MAX_LEN,
    ERROR_REASONS,
    LOAD_MAX_BYTES,
    LOAD_OFFSET_MAX,
    MEAS_NM_MAX,
    MEAS_NM_MIN,
    MEAS_REASONS,
    MEAS_SAMPLES,
    RATE_MAX,
    RATE_MIN,
    RESUME_MAX,
    STATUS_BITS,
    TC_TYPES,
    Ack,
    AxisService,
    BlockPiece,
    Channel,
    ChannelFault,
    CrcError,
    ErrorReply,
    Info,
    MeasReply,
    Message,
    ProtocolError,
    Sample,
    Status,
    StatusReport,
    status_names,
)

__all__ = [
    "InputError",  # what encode_* raise, as callers catch it from here
    "Ack",
    "AxisService",
    "BLOCK_LINE_BYTES",
    "BlockPiece",
    "CMD_MAX_LEN",
    "Channel",
    "ChannelFault",
    "CrcError",
    "ERROR_REASONS",
    "ErrorReply",
    "Info",
    "LINE_RE",
    "LOAD_MAX_BYTES",
    "LOAD_OFFSET_MAX",
    "MEAS_NM_MAX",
    "MEAS_NM_MIN",
    "MEAS_REASONS",
    "MEAS_SAMPLES",
    "MeasReply",
    "Message",
    "ProtocolError",
    "RATE_MAX",
    "RATE_MIN",
    "RESUME_MAX",
    "STATUS_BITS",
    "Sample",
    "Status",
    "StatusReport",
    "TC_TYPES",
    "assemble_block",
    "crc16",
    "decode",
    "encode",
    "encode_command",
    "encode_info",
    "encode_line",
    "encode_load",
    "encode_meas",
    "encode_meas_reply",
    "encode_sample",
    "encode_status",
    "parse_line",
    "status_names",
]
