"""The box's state, kept by the controller (issue 41: a power cut without a battery on VBAT).

The box keeps its filters, reference and output stage in retained memory; without a battery a
power cut takes them, and a ZERO afterwards starts the lag filters at today's temperatures (13
and 17 um off the clean run in `make faults`). The controller outlives the box's power, so the
component asks ``SNAP`` after each sample line while a datum is in force and keeps the block
(``$B`` pieces, then ``$OK,SNAP,<seq>``). After a cold boot (NO_REF) it gives the block back
(``LOAD`` pieces, one at a time: the box's receive buffer holds two commands) and then sends
``RESUME <n>``, with n counting the samples since the block's, so the box catches up over the
whole gap. The block is opaque here: the box checks its magic, model CRC and CRC-32 and refuses
(``$E,NO_STATE``) anything else, after which the component holds until ZERO as before.

With ``[box] state_file``, the block is also written to a file (atomically, with the model's
hash and the wall-clock time of its sample), so it survives a restart of the controller too.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from thermal_comp.contract import protocol


@dataclass
class Kept:
    """One whole block and the sample it describes."""

    block: bytes
    seq: int  # the box's seq of the latest sample when it sent the block
    wall_s: float  # time.time() when it arrived (for a controller that restarted since)


@dataclass
class StateKeeper:
    """The SNAP / LOAD conversation and the block kept; the component drives it."""

    model_hash: str | None
    path: Path | None = None
    kept: Kept | None = None
    snap_pending: bool = False
    pieces: list[protocol.BlockPiece] = field(default_factory=list)
    to_load: list[bytes] = field(default_factory=list)  # LOAD lines not yet acknowledged
    load_pending: bool = False
    asked_seq: int = 0  # the sample after which the outstanding SNAP was sent

    def __post_init__(self) -> None:
        if self.path is not None:
            self.kept = self._read()

    # ---- keeping -----------------------------------------------------------------------------
    def ask(self, seq: int) -> bytes | None:
        """The SNAP line to send after sample ``seq``, or None while an upload or an answer is
        outstanding (an answer not there two samples later was lost: asked again)."""
        if self.load_pending or self.to_load:
            return None
        if self.snap_pending and (seq - self.asked_seq) % 2**32 < 2:
            return None
        self.snap_pending, self.pieces, self.asked_seq = True, [], seq
        return b"SNAP\r\n"

    def take_piece(self, piece: protocol.BlockPiece) -> None:
        if self.snap_pending:
            self.pieces.append(piece)

    def snapped(self, seq: int) -> str | None:
        """``$OK,SNAP,<seq>``: the block is whole; None, or why it was not kept."""
        if not self.snap_pending:
            return f"$OK,SNAP,{seq} without a SNAP sent: ignored"
        self.snap_pending = False
        try:
            block = protocol.assemble_block(self.pieces)
        except protocol.InputError as exc:
            return f"state block not kept: {exc}"
        finally:
            self.pieces = []
        self.kept = Kept(block, seq, time.time())
        if self.path is not None:
            self._write(self.kept)
        return None

    def refused(self) -> bool:
        """An ``$E`` while SNAP was outstanding (NO_STATE: nothing to give yet) is its answer."""
        if not self.snap_pending:
            return False
        self.snap_pending, self.pieces = False, []
        return True

    # ---- giving it back ------------------------------------------------------------------
    def start_load(self) -> bytes | None:
        """After a cold boot: the first LOAD line (None: no block kept)."""
        if self.kept is None:
            return None
        self.snap_pending, self.pieces = False, []
        self.to_load = protocol.encode_load(self.kept.block)
        return self.next_load()

    def next_load(self) -> bytes | None:
        """The next LOAD line, or None when the whole block has been acknowledged."""
        if not self.to_load:
            self.load_pending = False
            return None
        self.load_pending = True
        return self.to_load.pop(0)

    def load_refused(self) -> bool:
        """An ``$E`` while a LOAD was outstanding: the upload is abandoned."""
        if not self.load_pending:
            return False
        self.load_pending, self.to_load = False, []
        return True

    def extra_periods(self, last_seq: int | None) -> int:
        """Samples the box took after the kept block's (the SNAP after them was not answered
        before the cut): RESUME must run them too."""
        if self.kept is None or last_seq is None:
            return 0
        ahead = (last_seq - self.kept.seq) % 2**32
        return ahead if ahead < 2**31 else 0

    def forget_pending(self) -> None:
        """The box restarted: an outstanding SNAP or LOAD will never be answered."""
        self.snap_pending, self.pieces = False, []
        self.load_pending, self.to_load = False, []

    # ---- the file --------------------------------------------------------------------------
    def _write(self, kept: Kept) -> None:
        assert self.path is not None
        tmp = self.path.with_name(self.path.name + ".tmp")
        tmp.write_text(json.dumps({"model_hash": self.model_hash, "seq": kept.seq,
                                   "wall_s": kept.wall_s, "block": kept.block.hex()}))
        os.replace(tmp, self.path)

    def _read(self) -> Kept | None:
        assert self.path is not None
        try:
            data = json.loads(self.path.read_text())
            if data.get("model_hash") != self.model_hash:
                return None  # another model's block: the box would refuse it anyway
            return Kept(bytes.fromhex(data["block"]), int(data["seq"]), float(data["wall_s"]))
        except (OSError, ValueError, KeyError, TypeError):
            return None
