"""The compiled layer's shape, found by parsing the package: no compiled function (``@njit``) takes more than
MAX_ARGUMENTS arguments; what belongs together travels as a named tuple of ``dynamics/structures.py``."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "crane_reference"
MAX_ARGUMENTS = 12


def test_no_compiled_function_takes_more_than_twelve_arguments():
    compiled, wide = 0, []
    for path in sorted(ROOT.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and any("njit" in ast.unparse(d) for d in node.decorator_list):
                compiled += 1
                count = len(node.args.posonlyargs) + len(node.args.args) + len(node.args.kwonlyargs)
                if count > MAX_ARGUMENTS:
                    wide.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({count})")
    assert compiled > 50  # the scan finds the kernels
    assert not wide, "compiled functions with more than 12 arguments: " + ", ".join(wide)
