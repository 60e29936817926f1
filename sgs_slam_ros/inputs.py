"""Which inputs are silent: the usual "no data" cause is one topic missing while the others arrive.

A node that synchronises RGB, depth, labels and camera_info makes no frame while any one of them is
missing (a segmentation node that is not running, a remap typo), and nothing else would say so.
Silence is only counted while the node is idle and waiting: a node busy with a slow frame (or a
lockstep player waiting for it) receives nothing, and that is not the inputs' fault. Inputs that
come apart from the frames (label images, fused when they come) are judged by wall-clock time
instead: the node keeps working without them.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

__all__ = ["InputWatch"]


class InputWatch:
    """Arrival times per input; reports inputs silent for ``stale_s`` while another one arrives.

    ``log`` is called once when an input becomes silent (and again only after it came back and went
    silent again). Times are wall-clock (monotonic): a silent topic is silent in any ROS time.
    """

    def __init__(
        self,
        topics: dict[str, str],
        log: Callable[[str], None],
        hint: dict[str, str] | None = None,
        apart: frozenset[str] = frozenset(),
    ) -> None:
        """``apart``: inputs the node works without (silence counted in wall-clock time, busy or idle)."""
        self.topics = topics  # input name -> resolved topic name
        self.apart = apart
        self.log, self.hint = log, hint or {}
        self.last: dict[str, float | None] = dict.fromkeys(topics)
        self.started = time.monotonic()
        self._reported: set[str] = set()
        self._lock = threading.Lock()

    def tick(self, name: str) -> None:
        """A message of input ``name`` arrived now."""
        with self._lock:
            self.last[name] = time.monotonic()
            self._reported.discard(name)

    def idle_s(self, name: str, now: float | None = None, idle_since: float | None = None) -> float:
        """Seconds input ``name`` has been silent while the node was idle (since ``idle_since``).

        Without ``idle_since``: seconds since it last arrived (since start if never).
        """
        now = time.monotonic() if now is None else now
        last = self.last[name]
        since = self.started if last is None else last
        return now - max(since, idle_since if idle_since is not None else since)

    def silent(self, stale_s: float, idle_since: float | None = None, only: frozenset[str] | None = None) -> list[str]:
        """Inputs silent for ``stale_s`` of the node's idle time while another input had one within ``stale_s``.

        ``idle_since``: when the node last became idle (monotonic s); silence before it is not counted
        (except for the ``apart`` inputs). ``only``: judge these inputs alone.
        """
        now = time.monotonic()
        with self._lock:
            fresh = [n for n in self.topics if self.last[n] is not None and now - self.last[n] <= stale_s]
            judged = [n for n in self.topics if only is None or n in only]
            quiet = [n for n in judged if self.idle_s(n, now, None if n in self.apart else idle_since) > stale_s]
            quiet = quiet if fresh else []
            new = [n for n in quiet if n not in self._reported]
            self._reported.update(new)
        for name in new:
            never = self.last[name] is None
            waited = "never received" if never else f"nothing for {self.idle_s(name, now):.0f} s"
            others = ", ".join(self.topics[n] for n in fresh)
            hint = f"; {self.hint[name]}" if name in self.hint else ""
            waits = "" if name in self.apart else " the node waits and"
            self.log(
                f"{self.topics[name]} is silent ({waited}) while{waits} {others} arrive{'s' * (len(fresh) == 1)}{hint}"
            )
        return quiet

    def silent_apart(self, stale_s: float) -> list[str]:
        """The ``apart`` inputs among :meth:`silent`'s (judged the same whether the node is busy or idle)."""
        return self.silent(stale_s, only=self.apart)

    def all_silent(self, stale_s: float, idle_since: float | None = None) -> bool:
        """No input had a message within ``stale_s`` of the node's idle time."""
        now = time.monotonic()
        return all(self.idle_s(n, now, idle_since) > stale_s for n in self.topics)

    def reset(self) -> None:
        """Forget the reports (they are logged again if the inputs stay silent)."""
        with self._lock:
            self._reported.clear()
