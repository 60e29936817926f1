"""No function longer than a screen: a long one is several steps that want names of their own."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("sgs_slam_core", "sgs_slam_ros", "msg_adapters", "bags", "bench", "test")
MAX_LINES = 60  # decorators excluded, docstring included


def long_functions(path: Path, root: Path = ROOT) -> list[str]:
    """``path:line name (N lines)`` (path relative to ``root``) for every function over ``MAX_LINES``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            lines = node.end_lineno - node.lineno + 1
            if lines > MAX_LINES:
                found.append(f"{path.relative_to(root)}:{node.lineno} {node.name} ({lines} lines)")
    return found


def test_long_functions_are_found(tmp_path):
    path = tmp_path / "probe.py"
    path.write_text("def f():\n" + "    x = 1\n" * MAX_LINES + "def g():\n    return 1\n")
    assert long_functions(path, tmp_path) == [f"probe.py:1 f ({MAX_LINES + 1} lines)"]


def test_no_function_is_over_a_screen():
    found = [
        hit for folder in FOLDERS for path in sorted((ROOT / folder).rglob("*.py")) for hit in long_functions(path)
    ]
    assert not found, f"functions over {MAX_LINES} lines:\n" + "\n".join(found)
