"""Failing file systems for tests: a full disk and a read-only folder, without root or a tmpfs.

* :class:`FullDisk` replaces the file object every output is written through
  (``sgs_slam_core.fileio._open_temp``) by one that accepts ``budget`` bytes in all, then fails
  like a full disk (``ENOSPC``), as a 200 KB tmpfs would.
* :func:`make_read_only` makes a folder read-only for real (``chmod``) when the tests do not run as
  root; root ignores permissions, so there the calls that create, rename or remove files inside it
  fail with ``EROFS`` instead, as on a read-only mount.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any, BinaryIO

import pytest

from sgs_slam_core import fileio

__all__ = ["FullDisk", "make_read_only"]


class _BudgetedFile:
    """A binary file whose writes draw on a shared byte budget."""

    def __init__(self, inner: BinaryIO, disk: FullDisk) -> None:
        self._inner, self._disk = inner, disk

    def write(self, data: bytes) -> int:
        size = len(memoryview(data).cast("B"))
        if size > self._disk.left:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._disk.left -= size
        return self._inner.write(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def __enter__(self) -> _BudgetedFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self._inner.close()


class FullDisk:
    """A disk with ``budget`` bytes free for every output written through :mod:`sgs_slam_core.fileio`."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, budget: int) -> None:
        self.left = budget
        monkeypatch.setattr(fileio, "_open_temp", lambda fd: _BudgetedFile(os.fdopen(fd, "wb"), self))


def _inside(root: Path, path: object) -> bool:
    try:
        target = Path(os.fsdecode(path)).absolute()  # type: ignore[arg-type]
    except TypeError:
        return False  # a file descriptor
    return target == root or root in target.parents


def make_read_only(folder: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Make ``folder`` (created if needed) read-only for the rest of the test; returns it."""
    folder.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        folder.chmod(0o555)  # pytest's tmp_path cleanup restores the permission
        return folder
    root = folder.absolute()

    def refuse(path: object) -> None:
        if _inside(root, path):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fsdecode(path))  # type: ignore[arg-type]

    def guard(original: Any, *, write_flags: bool = False) -> Any:
        def wrapped(path: Any, *args: Any, **kwargs: Any) -> Any:
            flags = args[0] if args else kwargs.get("flags", 0)
            if not write_flags or flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT):
                refuse(path)
            return original(path, *args, **kwargs)

        return wrapped

    monkeypatch.setattr(os, "open", guard(os.open, write_flags=True))
    for name in ("mkdir", "unlink", "remove", "rmdir"):
        monkeypatch.setattr(os, name, guard(getattr(os, name)))
    for name in ("replace", "rename"):
        original = getattr(os, name)

        def renamed(src: Any, dst: Any, *args: Any, _original: Any = original, **kwargs: Any) -> Any:
            refuse(src)
            refuse(dst)
            return _original(src, dst, *args, **kwargs)

        monkeypatch.setattr(os, name, renamed)
    return folder
