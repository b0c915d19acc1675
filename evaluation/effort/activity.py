"""What the equal-effort step says it is doing: :class:`MatchActivity`.

A knob search finishes no rollout of the run's count until its full pass (MPC's can run for many minutes on the
1000-sample effort set), so the progress line's status names the matches still running, how many are done, and
where each running one is: its search's latest try, or its full pass. Without it, the line named every controller
of the step, finished or not, for as long as the slowest one ran.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

#: Running matches named one by one in the status; more are counted.
SHOWN = 3


class MatchActivity:
    """The matches of one :meth:`~snac_gym.evaluation.effort.matching.EffortMatcher.match_all`, shown as a status.

    Thread-safe: the matches run concurrently (one thread each) when the executor is concurrent.

    Args:
        show: Where the status text goes (``Progress.status``); ``None``: nowhere.
        total: Matches of the step.
    """

    def __init__(self, show: Callable[[str], None] | None, total: int) -> None:
        self._show, self._total = show, total
        self._lock = threading.Lock()
        self._done = 0
        #: Where each running (task, controller) is, in the order they started.
        self._running: dict[tuple[str, str], str] = {}
        self._tries: dict[tuple[str, str], int] = {}

    @contextmanager
    def running(self, task: str, name: str) -> Iterator[None]:
        """One match, from its start to its end (however it ends)."""
        key = (task, name)
        with self._lock:
            self._running[key] = "starting"
            self._update()
        try:
            yield
        finally:
            with self._lock:
                self._running.pop(key, None)
                self._tries.pop(key, None)
                self._done += 1
                self._update()

    def tried(self, task: str, name: str) -> None:
        """The match's knob search measures one more knob value."""
        key = (task, name)
        with self._lock:
            if key in self._running:
                self._tries[key] = self._tries.get(key, 0) + 1
                self._running[key] = f"knob try {self._tries[key]}"
                self._update()

    def full_pass(self, task: str, name: str) -> None:
        """The match checks its knob on the whole set."""
        key = (task, name)
        with self._lock:
            if key in self._running:
                self._running[key] = "full pass"
                self._update()

    def text(self) -> str:
        """The status: ``matching effort (3 of 24 done): mpc on reach, knob try 5; …``; ``""`` once all are done."""
        with self._lock:
            return self._text()

    def _text(self) -> str:
        if not self._running:
            return ""
        entries = [f"{name} on {task}, {where}" for (task, name), where in self._running.items()]
        shown = "; ".join(entries[:SHOWN]) + (f"; {len(entries) - SHOWN} more" if len(entries) > SHOWN else "")
        return f"matching effort ({self._done} of {self._total} done): {shown}"

    def _update(self) -> None:
        if self._show is not None:
            self._show(self._text())


__all__ = ["SHOWN", "MatchActivity"]
