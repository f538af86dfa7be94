"""CRC-32 of the model tables, over the serialisation in docs/fixed-point.md.

The firmware recomputes the same bytes from its flash tables at boot (tcm_model_crc32) and
refuses to correct if they differ from TCM_MODEL_CRC32.
"""

from __future__ import annotations

import struct
import zlib

from thermal_comp.codegen.quantise import QModel


def serialise(model: QModel) -> bytes:
    """Little-endian, no padding: the exact byte stream the C runtime feeds its CRC."""
    out = bytearray(struct.pack("<IIII", len(model.channels), len(model.aux),
                                len(model.axes), model.period_ms))
    for ch in model.channels:
        out += struct.pack("<iiiiiBH", ch.min_code, ch.max_code, ch.window_lo_code,
                           ch.window_hi_code, ch.max_step_code, ch.tc_code,
                           ch.max_still_samples)
    for a in model.aux:
        out += struct.pack("<ii", a.min, a.max)
    for ax in model.axes:
        out += struct.pack("<BBqi", ax.shift, len(ax.terms), ax.intercept_q, ax.max_step_nm)
        sv = ax.service
        out += struct.pack("<BBIB4q", sv is not None, bool(sv and sv.p0_q8), *(
            (sv.g2_q8, sv.reopen_after, sv.q_q8, sv.r_q8, sv.floor2_nm2, sv.pmax_q8) if sv
            else (0,) * 6))
        for t in ax.terms:
            out += struct.pack("<BBBiq", t.kind_code, t.input, t.state or 0, t.param, t.coef_q)
    return bytes(out)


def model_crc32(model: QModel) -> int:
    return zlib.crc32(serialise(model)) & 0xFFFFFFFF
