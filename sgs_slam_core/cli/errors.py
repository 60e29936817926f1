"""How the command-line tools report a failure: one line on stderr and an exit code.

* a typed error of the project (:class:`SgsSlamError` and the packages' own bases) or an
  ``OSError``: the user's input or environment is at fault; its message, exit 1;
* running out of memory: what was asked is too big for this machine; exit 1;
* Ctrl-C: ``interrupted``, exit 130 (what a shell reports for SIGINT);
* anything else is a bug: one line with the exception, asking for a report, exit 70
  (``EX_SOFTWARE``); the traceback only with ``--debug`` (or ``SGS_SLAM_DEBUG=1``).

Usage errors (unknown options, out-of-range values) are argparse's: usage, one line, exit 2;
:class:`UsageError` is the same for arguments that only fail together.
"""

from __future__ import annotations

import os
import sys
import traceback
from typing import TextIO

from sgs_slam_core.errors import SgsSlamError

__all__ = [
    "EXIT_INTERNAL",
    "EXIT_INTERRUPTED",
    "EXIT_USAGE",
    "EXIT_USER",
    "UsageError",
    "debug_from_env",
    "describe",
    "report",
]

EXIT_USER = 1
EXIT_USAGE = 2
EXIT_INTERNAL = 70
EXIT_INTERRUPTED = 130
_OOM_TEXT = ("not enough memory", "can't allocate memory", "out of memory")


class UsageError(SgsSlamError):
    """Arguments that are valid one by one but not together (exit 2, like argparse's own errors)."""


def debug_from_env() -> bool:
    """``SGS_SLAM_DEBUG`` set to anything but empty or 0."""
    return os.environ.get("SGS_SLAM_DEBUG", "") not in ("", "0")


def _is_out_of_memory(err: BaseException) -> bool:
    if isinstance(err, MemoryError):
        return True
    return isinstance(err, RuntimeError) and any(t in str(err).lower() for t in _OOM_TEXT)  # torch's allocators


def _os_error_text(err: OSError) -> str:
    where = err.filename if err.filename is not None else ""
    reason = err.strerror or str(err)
    return f"{where}: {reason}" if where else reason


def _one_line(text: str) -> str:
    lines = [ln.strip() for ln in str(text).strip().splitlines() if ln.strip()]
    return " ".join(lines) if len(lines) <= 3 else f"{lines[0]} ... {lines[-1]}"


def describe(err: BaseException, user_errors: tuple[type[BaseException], ...] = ()) -> tuple[str, int, bool]:
    """``(one-line message, exit code, is a bug)`` for an exception that ended a command."""
    if isinstance(err, KeyboardInterrupt):
        return f"interrupted{': ' + _one_line(str(err)) if str(err) else ''}", EXIT_INTERRUPTED, False
    if isinstance(err, UsageError):
        return f"usage error: {_one_line(str(err))}", EXIT_USAGE, False
    if isinstance(err, (SgsSlamError, *user_errors)):
        return f"error: {_one_line(str(err))}", EXIT_USER, False
    if isinstance(err, OSError):
        return f"error: {_one_line(_os_error_text(err))}", EXIT_USER, False
    if _is_out_of_memory(err):
        return (
            f"error: out of memory ({type(err).__name__}: {_one_line(str(err)) or 'no details'}); "
            "use a smaller input, size or --max-frames",
            EXIT_USER,
            False,
        )
    text = _one_line(str(err))
    return (
        f"internal error: {type(err).__name__}{': ' + text if text else ''} -- this is a bug, please report it "
        "with the command line and the output of --debug",
        EXIT_INTERNAL,
        True,
    )


def report(
    prog: str,
    err: BaseException,
    debug: bool,
    user_errors: tuple[type[BaseException], ...] = (),
    stream: TextIO | None = None,
) -> int:
    """Print the one line (after the traceback with ``debug``) and return the exit code."""
    stream = stream or sys.stderr
    line, code, is_bug = describe(err, user_errors)
    if debug and not isinstance(err, KeyboardInterrupt):
        traceback.print_exception(err, file=stream)
    elif is_bug:
        line += " (run with --debug for the traceback)"
    print(f"{prog}: {line}", file=stream)
    return code
