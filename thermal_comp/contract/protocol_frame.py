"""The frame of every line the box sends: ``$<payload>*<CRC-16>`` and its check.

The decoder checks it and the encoders write it; scripts (frame_escape) inline the same check.
"""

from __future__ import annotations

import binascii
import re
from collections.abc import Iterable

LINE_RE = re.compile(rb"\$([\x20-\x7e]*)\*([0-9A-F]{4})(\r?\n)?")


def crc16(payload: bytes) -> int:
    """CRC-16/CCITT-FALSE of the bytes between ``$`` and ``*``."""
    return binascii.crc_hqx(payload, 0xFFFF)


def encode_line(kind: str, fields: Iterable[object]) -> bytes:
    """``$<kind>,<fields...>*<CRC>\\r\\n`` exactly as the box writes it."""
    payload = ",".join([kind, *(str(f) for f in fields)]).encode("ascii")
    return b"$" + payload + b"*" + f"{crc16(payload):04X}".encode() + b"\r\n"
