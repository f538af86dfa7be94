"""The firmware headers and the contract package state the same facts.

Each fact of the box contract has one home on the host side (``contract/``) and one in C
(``firmware/include/*.h``). This test reads the C macros independently (a small parser of
``#define NAME value`` lines, not the compiler) and fails when either side changes alone.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import pytest

from thermal_comp import contract
from thermal_comp.contract import (
    atomic_file,
    box,
    checkout,
    fixed_point,
    json_text,
    model_axis,
    model_checker,
    model_errors,
    model_file,
    model_hash,
    model_spec,
    protocol,
    protocol_decode,
    protocol_encode,
    protocol_frame,
    protocol_messages,
    terms,
)

INCLUDE = Path(__file__).resolve().parents[2] / "firmware" / "include"
DEFINE = re.compile(r"^\s*#\s*define\s+([A-Z0-9_]+)\s+(.+?)\s*(?:/\*.*)?$")


def _value(text: str) -> int | str:
    """The value of a simple macro: an integer expression of literals, or a string literal."""
    text = text.strip()
    if text.startswith('"'):
        return text.strip('"')
    expr = re.sub(r"\((?:uint16_t|uint32_t|int32_t|int64_t)\)", "", text)
    expr = re.sub(r"U?INT(?:32|64)_C\(([-0-9xA-Fa-f]+)\)", r"\1", expr)
    expr = re.sub(r"(?<=[0-9A-Fa-f])[uU]\b", "", expr)
    if not re.fullmatch(r"[-+0-9xA-Fa-f()<> ]+", expr):
        raise ValueError(f"not a simple macro: {text}")
    return int(eval(expr, {"__builtins__": {}}))  # noqa: S307 - literals and shifts only


def macros(header: str) -> dict[str, int | str]:
    out: dict[str, int | str] = {}
    for line in (INCLUDE / header).read_text(encoding="utf-8").splitlines():
        m = DEFINE.match(line)
        if m:
            try:
                out[m.group(1)] = _value(m.group(2))
            except (ValueError, SyntaxError):
                continue  # function-like or composite macros are not facts of the contract
    return out


def test_status_word_bits_match_status_h():
    c = macros("status.h")
    c_bits = {name[len("STATUS_"):]: v for name, v in c.items()
              if name.startswith("STATUS_") and name != "STATUS_H"}
    assert c_bits == {s.name: int(s) for s in protocol.Status}
    # the box's own channel fault bits (above the chip's SR byte), one home each
    c_faults = {name[len("CHFAULT_"):]: v for name, v in c.items()
                if name.startswith("CHFAULT_") and name != "CHFAULT_SR_MASK"}
    assert c_faults == {f.name: int(f) for f in protocol.ChannelFault if f > 0xFF}
    assert c["CHFAULT_SR_MASK"] == 0xFF


def test_model_runtime_matches_model_eval_h():
    c = macros("model_eval.h")
    assert c["TCM_RUNTIME_FORMAT"] == box.RUNTIME_FORMAT == box.HEADER_FORMAT
    assert c["TCM_MAX_CHANNELS"] == box.RUNTIME_MAX_CHANNELS
    assert c["TCM_MAX_AUX"] == box.RUNTIME_MAX_AUX
    assert c["TCM_MAX_AXES"] == box.RUNTIME_MAX_AXES
    assert c["TCM_MAX_STATES"] == box.RUNTIME_MAX_STATES
    kinds = {name[len("TCM_KIND_"):].lower(): v for name, v in c.items()
             if name.startswith("TCM_KIND_")}
    assert kinds == terms.KIND_CODES
    tc = {name[len("TCM_TC_"):]: v for name, v in c.items() if name.startswith("TCM_TC_")}
    assert tc == terms.TC_TYPES
    assert c["TCM_TEMP_FRAC_BITS"] == fixed_point.TEMP_FRAC_BITS
    assert c["TCM_STATE_FRAC_BITS"] == fixed_point.STATE_FRAC_BITS
    assert c["TCM_ALPHA_FRAC_BITS"] == fixed_point.ALPHA_FRAC_BITS
    assert c["TCM_CODE_MIN"] == fixed_point.CODE_MIN
    assert c["TCM_CODE_MAX"] == fixed_point.CODE_MAX
    assert c["TCM_ACC_LIMIT"] == fixed_point.ACC_LIMIT
    assert c["TCM_MAX_SHIFT"] == fixed_point.MAX_SHIFT


def test_box_capacity_and_version_match_box_config_h():
    c = macros("box_config.h")
    assert c["BOX_MAX_CHANNELS"] == box.BOX_CHANNELS
    assert c["BOX_MAX_AXES"] == box.BOX_AXES
    assert c["BOX_MAX_AUX"] == box.BOX_AUX
    assert c["BOX_FW_VERSION_DEFAULT"] == contract.__version__
    assert c["BOX_ZERO_SAMPLES"] == box.ZERO_SAMPLES


def test_command_limits_match_cmd_h():
    c = macros("cmd.h")
    assert c["CMD_MAX_LEN"] == protocol.CMD_MAX_LEN
    assert (c["CMD_RATE_MIN"], c["CMD_RATE_MAX"]) == (protocol.RATE_MIN, protocol.RATE_MAX)


def test_the_parser_reads_what_it_claims(tmp_path, monkeypatch):
    """The macro parser itself: a changed bit must show up as a changed value."""
    (tmp_path / "x.h").write_text("#define STATUS_HOLD ((uint16_t)1u << 3)\n"
                                  "#define TCM_CODE_MIN INT32_C(-262144)\n"
                                  '#define V "1.2.3"\n#define F(a) ((a) + 1)\n')
    monkeypatch.setattr(sys.modules[__name__], "INCLUDE", tmp_path)
    assert macros("x.h") == {"STATUS_HOLD": 8, "TCM_CODE_MIN": -262144, "V": "1.2.3"}


@pytest.mark.parametrize("mod", [contract, box, checkout, fixed_point, model_file, protocol,
                                 terms, model_errors, model_hash, json_text, atomic_file,
                                 model_spec, model_checker, model_axis, protocol_messages,
                                 protocol_frame, protocol_decode, protocol_encode])
def test_contract_is_stdlib_only(mod):
    """The contract imports no third-party package (the LinuxCNC side runs it on Debian's
    /usr/bin/python3 without the venv) and nothing of host, codegen or hil."""
    tree = ast.parse(Path(mod.__file__).read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                 else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
        for name in names:
            top = name.split(".")[0]
            allowed = (top == "__future__" or top in sys.stdlib_module_names
                       or name.startswith("thermal_comp.contract"))
            assert allowed, f"{mod.__name__} imports {name}"


def test_an_input_error_crosses_a_process_boundary_as_itself():
    """A malformed run found in a worker process (the benches, the forked folds) reaches the
    parent with its file, line and column, not as BrokenProcessPool."""
    import pickle
    from concurrent.futures import ProcessPoolExecutor

    from thermal_comp.host.io import RunFormatError

    err = RunFormatError("runs/a.csv", "not a number", line=7, column="T01")
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is RunFormatError and str(back) == str(err)
    assert (back.path, back.line, back.column) == ("runs/a.csv", 7, "T01")
    with ProcessPoolExecutor(max_workers=1) as pool:
        with pytest.raises(RunFormatError, match=r"runs/a\.csv, line 7, column 'T01'"):
            pool.submit(_raise_run_error).result()


def _raise_run_error():
    from thermal_comp.host.io import RunFormatError

    raise RunFormatError("runs/a.csv", "not a number", line=7, column="T01")
