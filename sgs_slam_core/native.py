"""Compiled CPU kernels, built on first use with ``torch.utils.cpp_extension`` (g++ and ninja).

Each :class:`NativeExtension` is one C++ source built into its own module the first time it is
needed (about a minute each), cached under ``TORCH_EXTENSIONS_DIR`` (default
``~/.cache/torch_extensions``) and loaded from there by later runs. The cache name carries a
fingerprint of the source's path and text, the compiler flags, the torch version and the CPU (builds
target ``-march=native``): an edited source never loads a stale build, and two checkouts never share
a cache entry (torch's build files name the source's path, so a shared entry would be rebuilt each
time the other checkout loads it, under the feet of a process running from it). ``render.backend:
torch`` never builds them (the pure-PyTorch kernels, :mod:`sgs_slam_core.kernels.reference`).
Importing this module builds nothing.

Builds of one extension are serialised across processes by an ``flock``, which the operating system
releases when its holder dies. torch's own build lock is a plain file that a killed build leaves behind,
after which every later load waits for it forever; holding the ``flock``, such a file can only be
stale, so it is removed.
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import platform
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType

import torch

from sgs_slam_core.errors import BackendUnavailableError
from sgs_slam_core.fileio import read_bytes

__all__ = ["NativeExtension", "prepare"]

log = logging.getLogger(__name__)

_CFLAGS = ("-O3", "-march=native", "-fopenmp", "-fno-math-errno", "-fno-trapping-math")


def _cpu_fingerprint() -> str:
    text = platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("flags", "model name")):
                text += line
                if len(text) > 4096:
                    break
    except OSError:
        pass
    return text


class NativeExtension:
    """One C++ source file built lazily into an importable module.

    ``stem``: short name in the cache (e.g. ``render``); ``what``: how the console names it
    (e.g. "the CPU renderer").
    """

    def __init__(self, stem: str, source: Path, what: str) -> None:
        self.stem, self.source, self.what = stem, source, what
        self._module: ModuleType | None = None
        self._error: str | None = None
        self._lock = threading.Lock()  # the ROS nodes' threads may ask for the module at once

    def cache_name(self, extra_cflags: tuple[str, ...] = ()) -> str:
        """The build's name under ``TORCH_EXTENSIONS_DIR``: stem and a fingerprint of what it depends on."""
        digest = hashlib.sha1()
        source = read_bytes(self.source, f"the source of {self.what}", BackendUnavailableError)
        flags = " ".join((*_CFLAGS, *extra_cflags)).encode()
        location = str(self.source.resolve()).encode()
        for part in (location, source, flags, torch.__version__.encode(), _cpu_fingerprint().encode()):
            digest.update(part)
        return f"sgs_slam_{self.stem}_{digest.hexdigest()[:12]}"

    def is_cached(self) -> bool:
        """True when a build for this source, flags, torch and CPU is already on disk (or loaded)."""
        if self._module is not None:
            return True
        from torch.utils.cpp_extension import _get_build_directory  # noqa: PLC0415 - heavy, and only needed here

        try:
            name = self.cache_name()
            # torch makes the directory: a read-only cache raises here, and module() reports it
            return (Path(_get_build_directory(name, verbose=False)) / f"{name}.so").is_file()
        except (BackendUnavailableError, OSError):  # no source or no cache to build in: module() says so
            return False

    def module(self) -> ModuleType:
        """The compiled module, building it on first call; raises :class:`BackendUnavailableError`."""
        if self._module is not None:
            return self._module
        with self._lock:
            return self._load_once()

    def _load_once(self) -> ModuleType:
        if self._module is not None:
            return self._module
        if self._error is not None:
            raise BackendUnavailableError(self._error)
        try:
            self._module = self._build(self.cache_name(), ())
        except Exception as err:
            first_line = next(iter(str(err).splitlines()), "")[:300]
            self._error = (
                f"cannot build {self.what} ({type(err).__name__}: {first_line}); it needs g++, ninja "
                "(pip install ninja) and a writable TORCH_EXTENSIONS_DIR; falling back to the PyTorch reference"
            )
            raise BackendUnavailableError(self._error) from err
        return self._module

    def variant(self, tag: str, extra_cflags: tuple[str, ...]) -> ModuleType:
        """The same source built with extra compiler flags under its own cache name.

        For tests of the code paths other CPUs take, e.g. ``("-mno-avx512f",)`` for the AVX2 build on
        an AVX-512 machine; :meth:`module` is unaffected. Raises what the build raises.
        """
        return self._build(f"{self.cache_name(extra_cflags)}_{tag}", extra_cflags)

    def is_available(self) -> bool:
        """True when the module is (or can be) built; the first call may take a minute."""
        try:
            self.module()
        except BackendUnavailableError:
            return False
        return True

    def unavailable_reason(self) -> str:
        """Why the module is unavailable (empty when it works or was never tried)."""
        return self._error or ""

    def _build(self, name: str, extra_cflags: tuple[str, ...]) -> ModuleType:
        from torch.utils.cpp_extension import _get_build_directory, load  # noqa: PLC0415 - heavy, only needed here

        build_dir = Path(_get_build_directory(name, verbose=False))
        with _exclusive(build_dir / "sgs_slam_build.flock"):
            _remove_stale_torch_lock(build_dir)
            return load(
                name=name,
                sources=[str(self.source)],
                extra_cflags=[*_CFLAGS, *extra_cflags],
                extra_ldflags=["-fopenmp"],
                verbose=bool(os.environ.get("SGS_SLAM_VERBOSE_BUILD")),
            )


@contextmanager
def _exclusive(path: Path) -> Iterator[None]:
    """An exclusive ``flock`` on ``path`` (created if missing) for the ``with`` block; waits for it.

    Raises :class:`BackendUnavailableError` when the lock file cannot be made (a read-only cache).
    """
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as err:
        raise BackendUnavailableError(f"cannot create the build lock {path}: {err}") from err
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


def _remove_stale_torch_lock(build_dir: Path) -> None:
    """Delete torch's build lock in ``build_dir``: called holding the flock, only a killed build left it."""
    stale = build_dir / "lock"
    if stale.exists():
        log.warning("removing %s, left by an interrupted build", stale)
        stale.unlink(missing_ok=True)


def prepare(extensions: Iterable[NativeExtension], announce: Callable[[str], None]) -> None:
    """Load (building where needed) every extension now, before anything is timed.

    ``announce`` gets one line per extension that has to be compiled (e.g. "building the CPU renderer
    (once, ~1 min)"); a failed build is left to the caller's fallback (it is remembered and warned
    about where the extension is used).
    """
    for ext in extensions:
        if ext.unavailable_reason():  # a build that failed is not tried again
            continue
        if not ext.is_cached():
            announce(f"building {ext.what} (once per machine and version, ~1 min)")
        ext.is_available()
