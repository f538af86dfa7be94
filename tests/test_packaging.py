"""The wheel (issue 44): one top-level name in site-packages, the files its commands read at run
time inside it, nothing written into the project's build/, and, installed away from the
checkout, the commands that need the checkout say so and exit 2 instead of a traceback."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    before = sorted(p.name for p in (ROOT / "build").iterdir()) if (ROOT / "build").is_dir() else []
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", str(ROOT),
                           "-w", str(out)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    after = sorted(p.name for p in (ROOT / "build").iterdir()) if (ROOT / "build").is_dir() else []
    assert after == before, "packaging wrote into the project's build/"
    return next(out.glob("thermal_comp-*.whl"))


@pytest.mark.slow
def test_one_top_level_name_with_its_run_time_files(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in names} == {"thermal_comp",
                                                f"{wheel.name.split('-py3')[0]}.dist-info"}
    for needed in ("thermal_comp/codegen/templates/model.h.j2",
                   "thermal_comp/cnc/config/thermalcomp.hal",
                   "thermal_comp/cnc/config/subroutines/probe_ref.ngc"):
        assert needed in names, needed


@pytest.mark.slow
@pytest.mark.parametrize("module, needs", [
    (["thermal_comp.hil", "replay", "--model", "m.json", "--data", "r.csv"], "firmware/Makefile"),
    (["thermal_comp.cnc"], "examples/sim_random.csv"),
    (["thermal_comp.cnc.faults"], "examples/sim_constant.csv"),
    (["thermal_comp.host.demo"], "examples/fl_thermal_steps.csv"),
])
def test_away_from_the_checkout_a_command_says_what_it_needs(wheel, tmp_path, module, needs):
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    env = {k: v for k, v in os.environ.items() if k != "THERMAL_COMP_CHECKOUT"}
    env["PYTHONPATH"] = str(site)
    proc = subprocess.run([sys.executable, "-m", *module], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert needs in proc.stderr and "THERMAL_COMP_CHECKOUT" in proc.stderr
    assert str(site) in proc.stderr  # the wheel's package ran, not the checkout's
    assert "Traceback" not in proc.stderr
