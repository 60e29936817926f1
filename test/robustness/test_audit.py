"""The grep-level audit, kept: library code reads user files only under a typed error and writes only atomically.

* Every call that parses or opens a file (``open``, ``Path.read_text``, ``yaml.safe_load``,
  ``json.loads``, ``torch.load``, ...) sits in a ``try`` with a handler, or reads what
  ``sgs_slam_core.fileio`` returned (which raises the typed error itself).
* No output is written around ``sgs_slam_core.fileio`` (``cv2.imwrite``, ``np.savetxt``,
  ``Path.write_text``, ``torch.save`` to a path ...): those are not atomic and fail silently or
  with a raw ``OSError``.

Exceptions are listed with their reason.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("sgs_slam_core", "bags", "msg_adapters", "sgs_slam_ros")
READS = {"open", "read_text", "read_bytes", "safe_load", "load", "loads", "loadtxt", "imread", "fromfile"}
WRITES = {"imwrite", "savetxt", "write_text", "write_bytes", "save", "dump", "to_csv"}
FILEIO_READERS = {"read_text", "read_bytes", "read_image"}  # fileio's own: they raise the typed error
ALLOWED = {
    ("sgs_slam_core/fileio.py", "*"): "the one place that reads and writes files",
    ("sgs_slam_core/native.py", "read_text"): "/proc/cpuinfo, not user input",
    ("sgs_slam_core/config/loader.py", "read_text"): "the package's own preset files",
    ("sgs_slam_core/config/loader.py", "safe_load"): "the package's own preset files (overrides are in a try)",
    ("sgs_slam_core/mapio/native.py", "save"): "torch.save into an in-memory buffer, written by fileio",
    ("bags/mcap_index.py", "open"): "McapIndex is built by bags.reader.open_index and bags.info under try -> BagError",
}


def _name(call: ast.Call) -> str:
    f = call.func
    return f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""


def _module_of(call: ast.Call) -> str:
    f = call.func
    return f.value.id if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) else ""


def _is_read(call: ast.Call) -> bool:
    name, module = _name(call), _module_of(call)
    if name in ("load", "loads"):
        return module in ("yaml", "json", "torch", "pickle", "np")
    if name == "safe_load":
        return module == "yaml"
    return name in READS and not (isinstance(call.func, ast.Name) and name in FILEIO_READERS)


def _is_write(call: ast.Call) -> bool:
    name, module = _name(call), _module_of(call)
    if name in ("save", "dump"):
        return module in ("torch", "np", "json", "pickle")
    if name in ("write_text", "write_bytes"):
        return isinstance(call.func, ast.Attribute)  # Path methods; fileio's functions are plain names
    return name in WRITES


def _reads_fileio(call: ast.Call) -> bool:
    """``yaml.safe_load(read_text(...))``: the argument comes from fileio, which raised already."""
    return any(isinstance(a, ast.Call) and _name(a) in FILEIO_READERS for a in call.args)


def _findings(path: Path) -> list[str]:
    rel = path.relative_to(REPO).as_posix()
    if (rel, "*") in ALLOWED:
        return []
    tree = ast.parse(path.read_text())
    guarded: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Try) and node.handlers:
            guarded |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    out = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = _name(node)
        if (rel, name) in ALLOWED:
            continue
        if _is_write(node):
            out.append(f"{rel}:{node.lineno}: {name}() writes around sgs_slam_core.fileio (not atomic)")
        elif _is_read(node) and id(node) not in guarded and not _reads_fileio(node):
            out.append(f"{rel}:{node.lineno}: {name}() reads a file outside a try and outside fileio")
    return out


def test_library_code_reads_under_typed_errors_and_writes_atomically():
    files = sorted(p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py"))
    assert len(files) > 50
    findings = [f for p in files for f in _findings(p)]
    assert not findings, "\n".join(findings)


@pytest.mark.parametrize(
    ("source", "found"),
    [
        ("import cv2\ncv2.imwrite('a.png', x)\n", "imwrite() writes"),
        ("from pathlib import Path\nPath('a').write_text('x')\n", "write_text() writes"),
        ("import yaml\nyaml.safe_load(open('a'))\n", "reads a file outside a try"),
        ("import numpy as np\nnp.loadtxt('a')\n", "loadtxt() reads"),
    ],
)
def test_the_audit_finds_what_it_looks_for(tmp_path, monkeypatch, source, found):
    fake = REPO / "sgs_slam_core" / "_audit_probe.py"
    monkeypatch.setattr(Path, "read_text", lambda self, *a, **k: source if self == fake else "")
    assert any(found in f for f in _findings(fake))
    ok = "from sgs_slam_core.fileio import read_text, write_text\nimport yaml\nyaml.safe_load(read_text(p, 'x'))\n"
    monkeypatch.setattr(Path, "read_text", lambda self, *a, **k: ok)
    assert _findings(fake) == []
