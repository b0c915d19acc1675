"""Plain progress lines for long runs whose output is not a terminal (a log file, CI).

A tqdm bar redraws one line in place, which a terminal shows and a log file records as one
line at the end (or not at all: tqdm turns itself off where its stream is not a terminal).
:class:`ProgressLines` writes ordinary lines instead, such as::

    evaluate: 600/800 rollouts (75 %), 9.5 s, matching effort (1 of 2 done): mpc on track, knob try 6

at a bounded rate: when another ``every_fraction`` of the total is done or ``every_s`` seconds
have passed since the last line, whichever comes first (checked as work is counted), and when
the total is reached; :meth:`ProgressLines.heartbeat` repeats the line when a long job finishes nothing for a
while. It
writes nothing by itself: the caller passes the function that writes (the CLI gives one that
writes to stderr, so that the results on stdout stay clean).
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Callable, TextIO


def wants_lines(stream: TextIO | None = None) -> bool:
    """Whether progress should be plain lines: ``stream`` (default ``sys.stderr``) is not a terminal.

    Args:
        stream: The stream the progress goes to.

    Returns:
        ``True`` where ``stream`` is not a terminal (or cannot tell).
    """
    stream = sys.stderr if stream is None else stream
    try:
        return not stream.isatty()
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return True


def format_elapsed(seconds: float) -> str:
    """``12.3 s`` under two minutes, else ``4.5 min``."""
    return f"{seconds:.1f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def compiling_line(command: str, when: str) -> str:
    """What ``command`` says as its first numba kernel compiles (a load from numba's cache says nothing,
    :func:`snac_gym.kernels.compiled.on_first_compile`): ``when`` says where in the run it is."""
    return (
        f"{command}: compiling the numerical kernels for this machine {when} (numba's cache has none for this code "
        "yet: the first run after an install or an update; seconds to tens of seconds)"
    )


class ProgressLines:
    """Rate-limited progress lines ``<label> <done>/<total> <unit> (<pct> %), <elapsed>[, <detail>]``.

    Args:
        label: What runs, the start of each line (``"evaluate:"``, ``"train-ppo: reach"``).
        total: Units of work in all (may grow, see :meth:`add_total`).
        write: Writes one line (no newline given).
        unit: Name of the unit of work (``"rollouts"``, ``"timesteps"``).
        every_fraction: Write when this much more of the total is done since the last line.
        every_s: Write when this long has passed since the last line (checked at each update).
        clock: Seconds, monotonic (a parameter for the tests).
    """

    def __init__(
        self,
        label: str,
        total: int,
        write: Callable[[str], object],
        unit: str = "rollouts",
        every_fraction: float = 0.1,
        every_s: float = 10.0,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.label, self.total, self.unit = label, int(total), unit
        self.every_fraction, self.every_s = float(every_fraction), float(every_s)
        self._write, self._clock = write, clock
        self.done = 0
        self.detail = ""
        self._start = self._last_time = clock()
        self._last_done = 0
        self._lock = threading.Lock()  # the evaluator counts finished jobs from several threads

    def add_total(self, count: int) -> None:
        """Add ``count`` units to the total."""
        with self._lock:
            self.total += int(count)

    def update(self, count: int = 0, done: int | None = None, detail: str | None = None) -> bool:
        """Count ``count`` more units done (or set ``done``); write a line if one is due.

        Args:
            count: Units finished since the last call.
            done: Units finished in all, instead of ``count``.
            detail: Text after the counts (kept for later lines; ``""`` clears it).

        Returns:
            Whether a line was written.
        """
        with self._lock:
            self.done = int(done) if done is not None else self.done + int(count)
            if detail is not None:
                self.detail = detail
            now = self._clock()
            if self.done <= self._last_done:
                return False
            due = (
                now - self._last_time >= self.every_s
                or (self.total > 0 and (self.done - self._last_done) / self.total >= self.every_fraction)
                or self._last_done < self.total <= self.done  # the end, once
            )
            if due:
                self._write(self.line(now))
                self._last_time, self._last_done = now, self.done
            return due

    def heartbeat(self, quiet_s: float) -> bool:
        """Write the line again if none was written for ``quiet_s`` seconds, though no unit was finished (a long job:
        the elapsed time moves, so that a reader sees the run is alive). Returns whether a line was written."""
        with self._lock:
            now = self._clock()
            if now - self._last_time < quiet_s:
                return False
            self._write(self.line(now))
            self._last_time = now
            return True

    def line(self, now: float | None = None) -> str:
        """The line for the current state."""
        now = self._clock() if now is None else now
        share = f" ({100 * self.done / self.total:.0f} %)" if self.total > 0 else ""
        text = f"{self.label} {self.done}/{self.total} {self.unit}{share}, {format_elapsed(now - self._start)}"
        return f"{text}, {self.detail}" if self.detail else text
