"""The HIL outside a checkout says what it needs instead of a make error."""

from __future__ import annotations

import pytest

import thermal_comp.hil.build as build
from thermal_comp.contract import checkout


def test_no_firmware_sources_names_what_is_missing(tmp_path, monkeypatch):
    monkeypatch.setenv(checkout.ENV, str(tmp_path))  # a checkout without firmware/, as a wheel
    header = tmp_path / "model.h"
    header.write_text("/* no model */\n")
    with pytest.raises(checkout.CheckoutMissing,
                       match=r"HIL.*has no firmware/Makefile.*THERMAL_COMP_CHECKOUT"):
        build.build_firmware(header, tmp_path / "build")


# Directory names and build flags that a shell would run (issue 41): ``id`` prints "uid=" to
# stderr, ``>FILE`` creates FILE. The firmware Makefile must hand them to the compiler as text.
SHELL_NAME = "a'`id>&2`'b"
MAKE_NAME = "c$(MAKE)$$d"  # make would substitute these (make syntax is no path either)


def _make_native(header, out_dir, cflags: str):
    import subprocess

    target = out_dir / "thermal_box"
    cmd = ["make", "-s", "-C", str(build.firmware_dir()), "BOARD=native", f"MODEL={header}",
           f"BUILD={out_dir}", f"BOX_CFLAGS={cflags}", str(target)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    return proc, target


@pytest.mark.parametrize("name", [SHELL_NAME, MAKE_NAME])
def test_paths_and_flags_never_run_through_a_shell(tmp_path, name):
    from pathlib import Path

    header = Path(checkout.root()) / "build" / "model.h"
    if not header.is_file():
        pytest.skip("build/model.h missing: run make train")
    marker = tmp_path / "ran"
    weird = tmp_path / name
    weird.mkdir()
    (weird / "model.h").write_bytes(header.read_bytes())
    cflags = f"-DBOX_SLEW_NM_PER_S=500 -DTCB_UNUSED_FLAG=`>{marker}` -DTCB_UNUSED2=$(id>&2)"
    proc, target = _make_native(weird / "model.h", weird / "out", cflags)
    output = proc.stdout + proc.stderr
    assert "uid=" not in output, output
    assert not marker.exists()
    assert proc.returncode == 0, output
    assert target.is_file()
    # the flags reached the compiler (and the flags file) as the words given
    flags = (weird / "out" / "flags").read_text(encoding="utf-8")
    assert f"-DTCB_UNUSED_FLAG=`>{marker}`" in flags
    assert str(weird / "model.h") in flags


def test_a_make_function_in_a_path_is_refused_not_run(tmp_path):
    # make function calls need a blank, and make cannot take a path with blanks as a target:
    # the Makefile refuses it before it expands or runs anything
    d = tmp_path / "c$(shell id>&2)d"
    d.mkdir()
    (d / "model.h").write_text("/* never read */\n")
    proc, target = _make_native(d / "model.h", tmp_path / "out", "")
    assert "uid=" not in proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert "without blanks" in proc.stderr
    assert not target.exists()


def test_header_path_with_a_double_quote_is_refused(tmp_path):
    d = tmp_path / 'q"uote'
    d.mkdir()
    (d / "model.h").write_text("/* never read */\n")
    proc, target = _make_native(d / "model.h", d / "out", "")
    assert proc.returncode != 0
    assert "C string literal" in proc.stderr
    assert not target.exists()


def test_qemu_board_refuses_a_build_dir_the_shell_would_parse(tmp_path):
    import subprocess

    out = tmp_path / SHELL_NAME
    proc = subprocess.run(["make", "-n", "-C", str(build.firmware_dir()), "BOARD=qemu_uartfeed",
                           f"MODEL={checkout.root() / 'build' / 'model.h'}", f"BUILD={out}"],
                          capture_output=True, text=True)
    assert proc.returncode != 0
    assert "shell special characters" in proc.stderr
    assert "uid=" not in proc.stdout + proc.stderr
