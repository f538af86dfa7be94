"""Read a text file as UTF-8, or say exactly why it is not: file, line, character, byte.

Data loggers and spreadsheets write UTF-16 ("Unicode text"), Latin-1 or Windows-1252; a bare
``UnicodeDecodeError`` names neither the file nor the line. Every reader of user files (runs,
model.json) goes through ``read_utf8``. Stdlib only (floor 0).
"""

from __future__ import annotations

import codecs
from pathlib import Path

from thermal_comp.contract.errors import InputError


class EncodingError(InputError):
    """A file is not UTF-8; the message names the file, line, character and the bytes."""


_BOMS = ((codecs.BOM_UTF32_LE, "UTF-32 LE"), (codecs.BOM_UTF32_BE, "UTF-32 BE"),
         (codecs.BOM_UTF16_LE, "UTF-16 LE"), (codecs.BOM_UTF16_BE, "UTF-16 BE"))


def decode_utf8(data: bytes, path: str | Path) -> str:
    """``data`` decoded as UTF-8 (a UTF-8 byte-order mark is dropped); EncodingError otherwise."""
    for bom, name in _BOMS:
        if data.startswith(bom):
            raise EncodingError(
                f"{path}, line 1: the file is {name} (byte-order mark "
                f"{' '.join(f'{b:02X}' for b in bom)}), not UTF-8; save it as UTF-8 "
                "(spreadsheets: 'CSV UTF-8'), e.g. iconv -f UTF-16 -t UTF-8")
    if len(data) >= 4 and data[1:4:2] == b"\0\0" and data[0] and data[2]:
        raise EncodingError(f"{path}, line 1: the file looks like UTF-16 LE without a "
                            "byte-order mark (every other byte is 0), not UTF-8; save it as "
                            "UTF-8")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        start = exc.start
        line = data.count(b"\n", 0, start) + 1
        line_start = data.rfind(b"\n", 0, start) + 1
        column = len(data[line_start:start].decode("utf-8", errors="replace")) + 1
        bad = data[start:exc.end]
        guess = ""
        try:
            guess = f" (as Windows-1252 it would read {bad.decode('cp1252')!r})"
        except UnicodeDecodeError:
            pass
        raise EncodingError(
            f"{path}, line {line}, character {column}: byte "
            f"{' '.join(f'0x{b:02X}' for b in bad)} is not valid UTF-8{guess}; the file is "
            "probably Latin-1 / Windows-1252: save it as UTF-8, e.g. "
            "iconv -f WINDOWS-1252 -t UTF-8") from None


def read_utf8(path: str | Path) -> str:
    """The text of ``path`` (see ``decode_utf8``); OSError as usual when it cannot be read."""
    return decode_utf8(Path(path).read_bytes(), path)
