"""Ctrl-C during a long offline run: the first stops it cleanly, the second aborts.

:class:`StopRequest` turns the first SIGINT into a request the frame loop checks between frames
(the run folder is then written for the frames processed so far, with a note); a second SIGINT
raises ``KeyboardInterrupt`` at once (the run folder is removed).
"""

from __future__ import annotations

import signal
import sys
import threading
from types import FrameType, TracebackType

__all__ = ["RunInterrupted", "StopRequest"]


class RunInterrupted(KeyboardInterrupt):
    """A run stopped by Ctrl-C whose folder holds the frames processed before it (see the message)."""


class StopRequest:
    """Context manager: SIGINT sets :attr:`requested` (first) or raises ``KeyboardInterrupt`` (second).

    Outside the main thread (where Python cannot install signal handlers) it does nothing, and
    Ctrl-C keeps its default effect.
    """

    def __init__(self, message: str = "") -> None:
        self.requested = False
        self.message = message
        self._previous: object = None
        self._installed = False

    def __call__(self) -> bool:
        """True once a stop was requested (pass the object itself as the loop's ``should_stop``)."""
        return self.requested

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.requested:
            signal.signal(signal.SIGINT, signal.default_int_handler)
            raise KeyboardInterrupt
        self.requested = True
        if self.message:
            print(f"\n{self.message}", file=sys.stderr, flush=True)

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
            self._installed = True
        return self

    def __exit__(self, kind: type[BaseException] | None, err: BaseException | None, tb: TracebackType | None) -> None:
        if self._installed:
            signal.signal(signal.SIGINT, self._previous)  # type: ignore[arg-type]
            self._installed = False
