"""Temporary stand-in for host/protocol.py (decoder of docs/protocol.md) until it lands."""

from __future__ import annotations

import binascii
from dataclasses import dataclass

STATUS_BITS = ("MODEL_BAD", "HOLD", "SLEW", "CLAMP", "RANGE", "OPEN", "TC_FAULT", "AUX_FAULT",
               "WDT_RESET", "NO_DATA")


class ProtocolError(ValueError):
    pass


@dataclass
class Channel:
    channel: int
    sensor: str
    tc_type: str


@dataclass
class Info:
    fw_version: str
    model_hash: str
    crc_ok: bool
    period_ms: int
    axes: list[str]
    channels: list[Channel]


@dataclass
class Sample:
    seq: int
    status: int
    corrections_nm: list[int]
    temp_codes: list[int]


@dataclass
class Other:
    kind: str
    fields: list[str]


def status_names(status: int) -> list[str]:
    return [n for i, n in enumerate(STATUS_BITS) if status >> i & 1]


def decode(raw: bytes):
    if not raw.startswith(b"$"):
        raise ProtocolError("does not start with '$'")
    star = raw.rfind(b"*")
    if star < 0 or len(raw) - star - 1 != 4:
        raise ProtocolError("no '*CRC' trailer")
    payload = raw[1:star]
    try:
        crc = int(raw[star + 1:], 16)
    except ValueError:
        raise ProtocolError("CRC is not hex") from None
    if binascii.crc_hqx(payload, 0xFFFF) != crc:
        raise ProtocolError("CRC mismatch")
    try:
        fields = payload.decode("ascii").split(",")
    except UnicodeDecodeError:
        raise ProtocolError("non-ASCII bytes") from None
    kind = fields[0]
    try:
        if kind == "C":
            seq, status, n_axes = int(fields[1]), int(fields[2], 16), int(fields[3])
            corr = [int(x) for x in fields[4:4 + n_axes]]
            n_ch = int(fields[4 + n_axes])
            temps = [int(x) for x in fields[5 + n_axes:5 + n_axes + n_ch]]
            if len(corr) != n_axes or len(temps) != n_ch or len(fields) != 5 + n_axes + n_ch:
                raise ProtocolError("field count does not match the declared counts")
            return Sample(seq, status, corr, temps)
        if kind == "I":
            axes = [a for a in fields[5].split(";") if a]
            chans = []
            for item in fields[6].split(";") if len(fields) > 6 else []:
                if item:
                    ch, sensor, tc = item.split(":")
                    chans.append(Channel(int(ch), sensor, tc))
            return Info(fields[1], fields[2], fields[3] == "OK", int(fields[4]), axes, chans)
    except (IndexError, ValueError) as exc:
        if isinstance(exc, ProtocolError):
            raise
        raise ProtocolError(f"malformed ${kind} line: {exc}") from None
    return Other(kind, fields[1:])
