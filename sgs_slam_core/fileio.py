"""Files at the boundary: user files read with a typed error that names them, outputs written atomically.

Every output goes to a temporary file beside its target, is flushed to disk and renamed over the
target, so whatever goes wrong (disk full, read-only folder, Ctrl-C, a crash) the target is either
absent (or its previous version) or complete. An ``OSError`` while writing becomes
:class:`~sgs_slam_core.errors.OutputError` naming the path; an ``OSError`` while reading becomes
the caller's error class (``DatasetError`` by default) naming the file.

Text is UTF-8; bytes that are not UTF-8 are kept as surrogates (Python's ``surrogateescape``, as
for file names), so a Latin-1 list of file names still names the files it lists.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import cv2
import numpy as np
import yaml

from sgs_slam_core.errors import DatasetError, OutputError, SgsSlamError

__all__ = [
    "MAX_TEXT_BYTES",
    "atomic_write",
    "make_dir",
    "read_bytes",
    "read_image",
    "read_text",
    "write_bytes",
    "write_image",
    "write_text",
]

MAX_TEXT_BYTES = 256 * 2**20  # a text input (list, trajectory, YAML) larger than this is refused
TEXT_ERRORS = "surrogateescape"


def _read_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_FILE_MODE = 0o666 & ~_read_umask()  # what open() would give: mkstemp's files are 0600


def _reason(err: OSError, path: Path) -> str:
    """``strerror``, plus the path the system names when it is not ``path`` itself."""
    text = err.strerror or str(err)
    other = err.filename if isinstance(err.filename, str) else None
    return f"{text} ({other})" if other and Path(other) != path else text


def _open_temp(fd: int) -> BinaryIO:
    """The file object written to (a seam: tests replace it to fake a full disk)."""
    return os.fdopen(fd, "wb")


def make_dir(path: str | Path) -> Path:
    """``mkdir -p``; failure raises :class:`OutputError` naming the folder."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"cannot create folder {path}: {_reason(err, path)}") from err
    return path


def atomic_write(path: str | Path, write: Callable[[BinaryIO], None]) -> None:
    """Call ``write(file)`` on a temporary file beside ``path``, then rename it over ``path``.

    If anything fails (or the process is interrupted), ``path`` is untouched and the temporary file
    is removed; an ``OSError`` is raised as :class:`OutputError` naming ``path``.
    """
    path = Path(path)
    make_dir(path.parent)
    tmp: Path | None = None
    try:
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        tmp = Path(name)
        os.fchmod(fd, _FILE_MODE)
        with _open_temp(fd) as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        tmp = None
    except OSError as err:
        raise OutputError(f"cannot write {path}: {_reason(err, path)}") from err
    finally:
        if tmp is not None:
            tmp.unlink(missing_ok=True)


def write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` atomically."""
    atomic_write(path, lambda f: f.write(data))


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` as UTF-8, atomically."""
    write_bytes(path, text.encode("utf-8", errors=TEXT_ERRORS))


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Write an image atomically, as ``cv2.imwrite`` would (BGR or one channel; format from the suffix)."""
    path = Path(path)
    ok, buf = cv2.imencode(path.suffix or ".png", image)
    if not ok:
        raise OutputError(f"cannot encode {path}: {image.dtype} {image.shape} as {path.suffix or '.png'}")
    write_bytes(path, buf.tobytes())


def read_bytes(path: str | Path, what: str, error: type[SgsSlamError] = DatasetError) -> bytes:
    """The bytes of a user file; a missing or unreadable file raises ``error`` naming it as ``what``."""
    path = Path(path)
    try:
        return path.read_bytes()
    except OSError as err:
        raise error(f"cannot read {what} {path}: {_reason(err, path)}") from err


def read_text(
    path: str | Path, what: str, error: type[SgsSlamError] = DatasetError, max_bytes: int = MAX_TEXT_BYTES
) -> str:
    """A user text file (UTF-8; other bytes kept as surrogates); binary or oversized files raise ``error``."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as err:
        raise error(f"cannot read {what} {path}: {_reason(err, path)}") from err
    if size > max_bytes:
        raise error(f"{what} {path} is {size:,} bytes; a text file of at most {max_bytes:,} bytes is expected")
    data = read_bytes(path, what, error)
    nul = data.find(b"\0")
    if nul >= 0:
        raise error(f"{what} {path} is a binary file (byte {nul} is NUL), expected text")
    return data.decode("utf-8", errors=TEXT_ERRORS)


def read_yaml(path: str | Path, what: str, error: type[SgsSlamError] = DatasetError) -> Any:
    """A user YAML file (read as :func:`read_text`, parsed safely); invalid YAML raises ``error`` naming the file."""
    text = read_text(path, what, error)
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise error(f"{what} {path} is not valid YAML: {' '.join(str(err).split())}") from err


def read_image(path: str | Path, flags: int, what: str, error: type[SgsSlamError] = DatasetError) -> np.ndarray:
    """An image file decoded by OpenCV (``flags`` as for ``cv2.imread``); unreadable or corrupt raises ``error``.

    Read through Python, so any file name works (``cv2.imread`` fails on names that are not UTF-8).
    """
    path = Path(path)
    data = np.frombuffer(read_bytes(path, f"{what} image", error), dtype=np.uint8)
    try:
        img = cv2.imdecode(data, flags) if data.size else None
    except cv2.error as err:  # e.g. more pixels than OpenCV's limit
        raise error(f"cannot decode {what} image {path}: {str(err).strip().splitlines()[-1]}") from err
    if img is None:
        raise error(f"cannot decode {what} image {path} (corrupt or not an image)")
    return img
