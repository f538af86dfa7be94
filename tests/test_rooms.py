"""Rooms by job (issue 44): no Python file over FILE_LINES lines, no function over
FUNCTION_LINES. The rooms still over either are listed in tests/data/rooms_over.json with the
size they had when the limit came; such a room may shrink but not grow, a new one may not
appear, and one back within the limit must leave the list (so the list only gets shorter).

    python tests/test_rooms.py --write     # rewrite the list after a room was split
"""

from __future__ import annotations

import ast
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("thermal_comp", "bench")
FILE_LINES = 500
FUNCTION_LINES = 60
LIST = ROOT / "tests" / "data" / "rooms_over.json"


def measure(root: Path = ROOT) -> dict[str, int]:
    """Every file over FILE_LINES and function over FUNCTION_LINES: "path" or
    "path:qualified.name" -> lines."""
    over: dict[str, int] = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            text = path.read_text()
            rel = path.relative_to(root).as_posix()
            n = text.count("\n")
            if n > FILE_LINES:
                over[rel] = n
            for name, lines in _functions(ast.parse(text)):
                if lines > FUNCTION_LINES:
                    over[f"{rel}:{name}"] = lines
    return over


def _functions(tree: ast.AST, prefix: str = ""):
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            yield prefix + node.name, node.end_lineno - node.lineno + 1
            yield from _functions(node, f"{prefix}{node.name}.")
        elif isinstance(node, ast.ClassDef):
            yield from _functions(node, f"{prefix}{node.name}.")


def problems(now: dict[str, int], listed: dict[str, int]) -> list[str]:
    out = []
    for room, lines in sorted(now.items()):
        if room not in listed:
            out.append(f"{room}: {lines} lines, over the limit and not in {LIST.name}: split it")
        elif lines > listed[room]:
            out.append(f"{room}: grew from {listed[room]} to {lines} lines (over the limit: "
                       "it may only shrink)")
    for room in sorted(set(listed) - set(now)):
        out.append(f"{room}: within the limit now: drop it from {LIST.name} "
                   "(python tests/test_rooms.py --write)")
    return out


def test_no_room_grows_and_none_is_added():
    listed = json.loads(LIST.read_text())
    assert problems(measure(), listed) == []


def test_the_rule_can_fail(tmp_path):
    pkg = tmp_path / "thermal_comp" / "host"
    pkg.mkdir(parents=True)
    body = "\n".join(f"        x{i} = {i}" for i in range(FUNCTION_LINES))
    (pkg / "big.py").write_text(f"class A:\n    def f(self):\n{body}\n        return 0\n")
    now = {k: v for k, v in measure(tmp_path).items()}
    assert list(now) == ["thermal_comp/host/big.py:A.f"]
    assert problems(now, {})[0].startswith("thermal_comp/host/big.py:A.f: 62 lines, over the limit")
    assert "grew" in problems(now, {"thermal_comp/host/big.py:A.f": 61})[0]
    assert "within the limit now" in problems({}, {"thermal_comp/host/big.py:A.f": 61})[0]


if __name__ == "__main__" and sys.argv[1:] == ["--write"]:
    LIST.write_text(json.dumps(measure(), indent=1, sort_keys=True) + "\n")
    print(f"wrote {LIST}")
