"""Output files (model.json, model.h, its fixed_point block) get the mode any tool gives a new
file, 0o666 less the umask, not the 0600 of the temp file they are written through: the
LinuxCNC user or a colleague must be able to read them (issue 43)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from thermal_comp.codegen import fixed_point_path, write_header
from thermal_comp.contract.model_file import current_umask, write_model, write_text_atomic

MODEL = {
    "schema": "thermal-model/1", "tool_version": "0.1.0", "sample_period_s": 1.0,
    "channels": [{"channel": 0, "sensor": "T05", "tc_type": "K", "min_c": -40.0,
                  "max_c": 200.0}],
    "aux": [], "time_max_s": 604800.0,
    "axes": {"dx_um": {"unit": "um", "intercept": -12.5,
                       "terms": [{"kind": "temp", "source": "T05", "coef": 0.75}]}},
    "training": {"runs": [], "targets": ["dx_um"], "sensors": "T*"},
}


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


@pytest.fixture
def umask():
    old = os.umask(0o022)
    os.umask(old)

    def set_mask(mask: int) -> None:
        os.umask(mask)

    yield set_mask
    os.umask(old)


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o002])
def test_model_json_and_header_follow_the_umask(tmp_path, umask, mask):
    umask(mask)
    assert current_umask() == mask
    model_path = tmp_path / "model.json"
    write_model(dict(MODEL), model_path)
    header = tmp_path / "model.h"
    write_header(model_path, header)
    for path in (model_path, header, fixed_point_path(header)):
        assert mode(path) == 0o666 & ~mask, (path.name, oct(mode(path)))


def test_a_replaced_file_gets_the_umask_mode_not_the_old_one(tmp_path, umask):
    umask(0o022)
    path = tmp_path / "report.txt"
    path.write_text("old")
    path.chmod(0o600)
    write_text_atomic(path, "new")
    assert path.read_text() == "new" and mode(path) == 0o644
    assert not list(tmp_path.glob(".*.tmp"))  # no temp file left behind
