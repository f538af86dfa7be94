"""Build the firmware for a model: header from model.json (codegen), then the firmware Makefile.

The header is generated with ``codegen.generate`` into the HIL's own build directory, so the
user's model.json is never rewritten by a replay, and each (header, build flags) pair gets its
own firmware build directory: replays of different models (or a deliberately tampered header)
never overwrite each other's binaries, and make's own dependency tracking rebuilds a binary
when the firmware sources change.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

from thermal_comp.codegen import GeneratedHeader, generate, load_model
from thermal_comp.contract import checkout
from thermal_comp.contract.model_file import ModelSpec


def firmware_dir() -> Path:
    """The firmware's sources in the project's checkout (a wheel has none): the HIL builds the
    box from them."""
    return checkout.require("the HIL (it builds the box's firmware from its sources)",
                            "firmware/Makefile") / "firmware"


# What each board's build produces (firmware/Makefile, boards/qemu_uartfeed/board.mk).
TARGETS = {"native": "thermal_box", "stm32f405": "thermal_box.elf",
           "qemu_uartfeed": "qemu_uartfeed.elf"}


class BuildError(RuntimeError):
    """The firmware did not build; the message carries the compiler's output."""


@dataclass(frozen=True)
class ModelBuild:
    """A model and the header generated from it."""

    model: dict  # the file's content (written out again by the cnc session and the tests)
    generated: GeneratedHeader
    header_path: Path

    @property
    def spec(self) -> ModelSpec:
        """The model's function, typed: what the replay and its judges read."""
        return self.generated.spec

    def bound_um(self, axis: str) -> float:
        return float(self.generated.fixed_point["axes"][axis]["bound_um"])

    @property
    def zero_at_powerup(self) -> bool:
        return bool(self.generated.fixed_point.get("zero_at_powerup", False))


def prepare_header(model_json: str | Path, build_dir: str | Path,
                   zero_at_powerup: bool | None = None) -> ModelBuild:
    """Load model.json and write its header to ``build_dir/model-<hash>[-z].h`` (atomic);
    ``-z``: generated with ``--zero-at-powerup``."""
    model = load_model(model_json)
    gen = generate(model, zero_at_powerup=zero_at_powerup)
    build_dir = Path(build_dir)
    build_dir.mkdir(parents=True, exist_ok=True)
    zeroes = bool(gen.fixed_point.get("zero_at_powerup"))  # default: the model's reference
    header = build_dir / f"model-{gen.model.model_hash}{'-z' if zeroes else ''}.h"
    if not header.is_file() or header.read_text(encoding="utf-8") != gen.text:
        tmp = header.with_suffix(f".h.{os.getpid()}.tmp")
        tmp.write_text(gen.text, encoding="utf-8")
        tmp.replace(header)
    return ModelBuild(model, gen, header)


def _key(header: Path, cflags: str, board: str) -> str:
    h = hashlib.sha256(header.read_bytes())
    h.update(f"\0{board}\0{cflags}".encode())
    return h.hexdigest()[:12]


def build_firmware(header: str | Path, build_root: str | Path, board: str = "native",
                   cflags: str = "") -> Path:
    """Build ``board`` firmware against ``header``; returns the binary (native) or ELF image."""
    header = Path(header).resolve()
    out_dir = Path(build_root).resolve() / f"{board}-{_key(header, cflags, board)}"
    cmd = ["make", "-s", "-C", str(firmware_dir()), f"BOARD={board}", f"MODEL={header}",
           f"BUILD={out_dir}", f"BOX_CFLAGS={cflags}"]
    target = out_dir / TARGETS.get(board, "thermal_box.elf")
    cmd.append(str(target))
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0 or not target.is_file():
        raise BuildError(f"firmware build failed ({' '.join(cmd)}):\n"
                         f"{proc.stdout}{proc.stderr}".rstrip())
    return target
