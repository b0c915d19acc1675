"""Progress of a run over its rollouts, on stderr: :class:`Progress`.

The counting and the plain lines are :mod:`snac_gym.common.progress`'s (shared with ``train-ppo``);
this wraps them with a tqdm bar for a terminal and the status text of the evaluator's steps.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable

from snac_gym.common.progress import ProgressLines, wants_lines


class Progress:
    """Progress over rollouts: a tqdm bar on a terminal, plain lines elsewhere, nothing when disabled.

    Where stderr is a terminal the bar is drawn there; where it is not (a log file, CI) tqdm
    stays off and :class:`~snac_gym.common.progress.ProgressLines` writes lines such as
    ``evaluate: 600/800 rollouts (75 %), 9.5 s, matching effort (1 of 2 done): mpc on track, knob try 6``
    to stderr, every 10 % of the rollouts or 10 s, whichever comes first. ``enabled=False`` (``--no-progress``)
    writes neither.

    A job can run for minutes without finishing a rollout (MPC's effort search on the 1000-sample effort set): the
    bar is redrawn every second and a line is written again after :data:`QUIET_S` seconds without one, so that its
    elapsed time shows the run is alive (:meth:`~snac_gym.common.progress.ProgressLines.heartbeat`).

    Args:
        total: Rollouts expected (grows with :meth:`add_total`).
        enabled: Show progress at all.
        lines: Write plain lines; ``None``: where stderr is not a terminal.
        write: Where the plain lines go (default: one line on stderr, flushed).
        label: Start of each plain line.
        quiet_s: Seconds without a line after which the line is written again.
        tick_s: How often the bar is redrawn and the quiet time checked.
    """

    #: Seconds without a plain line after which it is written again.
    QUIET_S = 60.0

    def __init__(
        self,
        total: int,
        enabled: bool,
        lines: bool | None = None,
        write: Callable[[str], None] | None = None,
        label: str = "evaluate:",
        quiet_s: float = QUIET_S,
        tick_s: float = 1.0,
    ) -> None:
        # start-up time: every worker imports this; only the parent has a bar
        from tqdm.auto import tqdm

        self._bar = tqdm(total=total, unit="rollout", disable=None if enabled else True, dynamic_ncols=True)
        if lines is None:
            lines = wants_lines(sys.stderr)
        if write is None:

            def write(text: str) -> None:
                print(text, file=sys.stderr, flush=True)

        self._lines = ProgressLines(label, total, write) if enabled and lines else None
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None
        if enabled:
            self._beat = threading.Thread(
                target=self._heartbeat, args=(quiet_s, tick_s), name="progress-beat", daemon=True
            )
            self._beat.start()

    def _heartbeat(self, quiet_s: float, tick_s: float) -> None:
        while not self._stop.wait(tick_s):
            self._bar.refresh()  # the bar's elapsed time, between finished rollouts
            if self._lines is not None:
                self._lines.heartbeat(quiet_s)

    def add_total(self, count: int) -> None:
        """Expect ``count`` more rollouts."""
        self._bar.total += count
        self._bar.refresh()
        if self._lines is not None:
            self._lines.add_total(count)

    def update(self, count: int) -> None:
        """Count ``count`` finished rollouts (a line follows where one is due)."""
        self._bar.update(count)
        if self._lines is not None:
            self._lines.update(count)

    def status(self, text: str) -> None:
        """What runs now (the bar's postfix, the end of the next line); ``""`` clears it."""
        self._bar.set_postfix_str(text, refresh=True)
        if self._lines is not None:
            self._lines.detail = text

    def close(self) -> None:
        """Close the bar (and stop redrawing it)."""
        self._stop.set()
        if self._beat is not None:
            self._beat.join()
        self._bar.close()


__all__ = ["Progress"]
