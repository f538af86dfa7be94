"""The HIL outside a checkout says what it needs instead of a make error."""

from __future__ import annotations

import pytest

import hil.build as build


def test_no_firmware_sources_names_what_is_missing(tmp_path, monkeypatch):
    monkeypatch.setattr(build, "FIRMWARE_DIR", tmp_path / "firmware")
    header = tmp_path / "model.h"
    header.write_text("/* no model */\n")
    with pytest.raises(build.BuildError, match=r"no firmware/.*checkout.*--firmware"):
        build.build_firmware(header, tmp_path / "build")
