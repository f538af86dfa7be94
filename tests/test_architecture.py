"""The import rule of docs/architecture.md: each floor imports only the floors below it.

Read from the source (ast), not from what happens to be imported at run time, so a new import
anywhere (also inside a function) that runs back up fails here. Also: no circles between
modules, and no module imports another module's private (``_``) names.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "thermal_comp"  # the one installed package; its parts are named without it below
PACKAGES = ("contract", "codegen", "hil", "host", "cnc", "bench")

# unit -> the units it may import (besides itself). Mirrors the table in docs/architecture.md.
BELOW = {
    "contract": set(),
    "codegen": {"contract"},
    "host.progress": set(),
    "host.parallel": {"host.progress"},
    "host.io": {"contract"},
    "host.fitting": {"contract", "host.io", "codegen"},  # step_limits: the box's code quantisation
    "host.sim": {"contract", "host.io", "host.fitting", "host.progress"},
    "host.selection": {"contract", "host.io", "host.fitting", "host.progress"},
    "host.effects": {"contract", "host.io", "host.fitting", "host.selection", "host.progress"},
    # in service (issue 42): probe readings, the gate, the estimators, their parameters
    "host.service": {"contract", "host.io", "host.fitting", "host.progress"},
    "host.train": {"contract", "host.io", "host.fitting", "host.selection", "host.effects",
                   "host.progress", "host.parallel", "host.service"},
    "host.analysis": {"contract", "codegen", "host.io", "host.fitting", "host.selection",
                      "host.effects", "host.train", "host.sim", "host.progress",
                      "host.service"},
    "host.box": {"contract", "codegen"},
    # the fleet over MQTT (issue 45): the protocol decoder, and the run writer for export
    "host.fleet": {"contract", "host.io"},
    "hil": {"contract", "codegen", "host.io", "host.fitting", "host.progress",
            "host.service"},  # hil replay --probe-*: the probe readings as host evaluate makes them
    # the LinuxCNC side: the HAL component and the headless driver run under Debian's
    # /usr/bin/python3 with the contract only; the session (make cnc) builds with the rest
    "cnc.thermalcomp": {"contract", "cnc.compconfig", "cnc.compensator", "cnc.serialport"},
    "cnc.compensator": {"contract", "cnc.compconfig", "cnc.keptstate", "cnc.serialport"},
    "cnc.compconfig": {"contract"},
    "cnc.serialport": set(),
    "cnc.keptstate": {"contract"},
    "cnc.driver": {"contract", "cnc.machine", "cnc.tap"},
    "cnc.machine": {"cnc.tap"},
    "cnc.tap": {"contract"},
    "cnc": {"contract", "codegen", "hil", "host.io", "host.fitting", "host.sim",
            "host.progress", "cnc.thermalcomp"},
    # the benches measure every floor from above; nothing imports them (bench/goal.py, the
    # accuracy bench's case record and the runner are their own; no circle among them)
    "bench": {"contract", "codegen", "hil", "cnc", "host.progress", "host.parallel", "host.io",
              "host.fitting", "host.sim", "host.selection", "host.effects", "host.service",
              "host.train", "host.analysis", "host.box", "host.fleet"},
}
TOP = ("host.cli", "host.commands", "host.demo", "host.demo_baseline", "host.__main__",
       "host")  # may import any wing
UNITS = sorted(BELOW, key=len, reverse=True)


def module_name(path: Path) -> str:
    """The module's name within the project: ``host.io.load`` for host/io/load.py."""
    base = ROOT / PACKAGE if path.is_relative_to(ROOT / PACKAGE) else ROOT
    parts = list(path.relative_to(base).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def part_name(module: str) -> str:
    """``thermal_comp.host.io`` -> ``host.io``; other modules as they are."""
    return module.removeprefix(PACKAGE + ".")


def source_dir(pkg: str) -> Path:
    return ROOT / pkg if pkg == "bench" else ROOT / PACKAGE / pkg


def unit_of(module: str) -> str | None:
    for unit in UNITS:
        if module == unit or module.startswith(unit + "."):
            return unit
    return None


def imports() -> dict[str, set[tuple[str, str | None]]]:
    """module -> {(imported module, imported name or None)} over every import statement."""
    out: dict[str, set[tuple[str, str | None]]] = defaultdict(set)
    for pkg in PACKAGES:
        for path in sorted(source_dir(pkg).rglob("*.py")):
            me = module_name(path)
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Import):
                    out[me] |= {(part_name(a.name), None) for a in node.names}
                elif isinstance(node, ast.ImportFrom) and node.module == PACKAGE:
                    out[me] |= {(a.name, None) for a in node.names}  # from thermal_comp import x
                elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                    out[me] |= {(part_name(node.module), a.name) for a in node.names}
    return out


def _project(module: str) -> bool:
    return module.split(".")[0] in PACKAGES


def test_every_module_belongs_to_a_floor():
    for me in imports():
        assert unit_of(me) or me in TOP or me.startswith("host.commands"), me


def upward(deps_of: dict[str, set[tuple[str, str | None]]]) -> list[str]:
    """Imports that run against the floors."""
    bad = []
    for me, deps in deps_of.items():
        mine = unit_of(me)
        if mine is None:  # cli, commands, demo: the top floor
            continue
        for module, name in deps:
            if not _project(module):
                continue
            target = unit_of(f"{module}.{name}" if name else module) or unit_of(module) or module
            if target != mine and target not in BELOW[mine]:
                bad.append(f"{me} imports {module}{'.' + name if name else ''} ({target})")
    return sorted(bad)


def test_no_import_runs_back_up():
    bad = upward(imports())
    assert not bad, "imports against docs/architecture.md:\n" + "\n".join(bad)


def test_no_module_imports_a_private_name_of_another():
    bad = [f"{me}: from {module} import {name}" for me, deps in imports().items()
           for module, name in deps
           if name and name.startswith("_") and not name.startswith("__") and _project(module)
           and module != me]
    assert not bad, "\n".join(bad)


def test_no_import_circles_between_modules():
    graph = {me: {m for m, _ in deps if _project(m)} | {f"{m}.{n}" for m, n in deps
                                                        if n and _project(m)}
             for me, deps in imports().items()}
    graph = {me: {d for d in deps if d in graph and d != me} for me, deps in graph.items()}
    done: set[str] = set()

    def visit(node: str, stack: list[str]) -> None:
        if node in stack:
            cycle = stack[stack.index(node):] + [node]
            # a package importing its own submodules is not a circle unless they import it back
            raise AssertionError("import circle: " + " -> ".join(cycle))
        if node in done:
            return
        for dep in sorted(graph.get(node, ())):
            if dep.startswith(node + "."):
                continue  # a face re-exporting its own modules
            visit(dep, [*stack, node])
        done.add(node)

    for module in sorted(graph):
        visit(module, [])


def bare_part_imports(root: Path = ROOT) -> list[str]:
    """Imports of a part by its bare name (``import host``, ``from cnc.x import y``): the parts
    live only inside the one installed package, so such an import finds nothing in a wheel, or
    another project's module of that name."""
    bad = []
    for folder in (PACKAGE, "bench", "tests", "scripts", "firmware"):
        for path in sorted((root / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                         [node.module] if isinstance(node, ast.ImportFrom) and node.module
                         and not node.level else [])
                bad += [f"{path.relative_to(root)}: {n}" for n in names
                        if n.split(".")[0] in PACKAGES and n.split(".")[0] != "bench"]
    return bad


def test_the_parts_are_imported_through_the_one_package():
    assert bare_part_imports() == []


def test_a_bare_part_import_is_found(tmp_path):
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "t.py").write_text("import os\nfrom host.io import load_run\n")
    assert bare_part_imports(tmp_path) == ["tests/t.py: host.io"]


def test_the_rule_can_fail():
    """The checker flags an upward import and a contract that reaches into host."""
    deps = imports()
    deps["host.effects.search"] = deps["host.effects.search"] | {("host.train", "train_model")}
    deps["contract.terms"] = deps["contract.terms"] | {("host.io.runs", None)}
    assert upward(deps) == ["contract.terms imports host.io.runs (host.io)",
                            "host.effects.search imports host.train.train_model (host.train)"]


# ---- firmware: the boards implement the HAL and reach nothing of the application ---------------
FIRMWARE = ROOT / "firmware"
# what a board may include from outside its own folder: the HAL contract, the box's build
# configuration (channel count, timeouts) and the shared MAX31856 register model
BOARD_MAY_INCLUDE = {p.name for p in (FIRMWARE / "hal").glob("*.h")} | {"box_config.h"} | {
    p.name for p in (FIRMWARE / "emul").glob("*.h")}


def board_includes_outside(board: Path) -> list[str]:
    import re

    own = {p.name for p in board.glob("*.h")} | {"board_internal.h", "stm32f405_regs.h"}
    bad = []
    for src in sorted(board.glob("*.[ch]")):
        for name in re.findall(r'^\s*#\s*include\s+"([^"]+)"', src.read_text(), re.M):
            if name not in own | BOARD_MAY_INCLUDE:
                bad.append(f"{src.name}: {name}")
    return bad


def test_boards_include_only_the_hal_contract():
    boards = sorted(p for p in (FIRMWARE / "boards").iterdir() if p.is_dir())
    assert {b.name for b in boards} >= {"native", "stm32f405", "qemu_uartfeed"}
    assert not list((FIRMWARE / "hal").glob("*.c")), "hal/ holds the contract (headers) only"
    for board in boards:
        assert board_includes_outside(board) == [], board.name


def test_the_board_rule_can_fail(tmp_path):
    (tmp_path / "main.c").write_text('#include "hal_board.h"\n#include "app.h"\n')
    assert board_includes_outside(tmp_path) == ["main.c: app.h"]
