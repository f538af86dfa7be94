"""The words of the box's wire protocol (docs/protocol.md): limits, status bits, the records.

What a line means, apart from how it is written or read: the decoder, the encoders and every
caller share these types, so a field added here shows up everywhere at once.
"""

from __future__ import annotations

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
# SNAP / LOAD (docs/protocol.md, "Commands"): the box's state block, sent
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
