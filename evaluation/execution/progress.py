"""Progress of a run over its rollouts, on stderr: :class:`Progress`.

The counting and the plain lines are :mod:`snac_gym.common.progress`'s (shared with ``train-ppo``);
this wraps them with a tqdm bar for a terminal and the status text of the evaluator's steps.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from snac_gym.common.progress import ProgressLines, wants_lines


class Progress:
    """Progress over rollouts: a tqdm bar on a terminal, plain lines elsewhere, nothing when disabled.

    Where stderr is a terminal the bar is drawn there; where it is not (a log file, CI) tqdm
    stays off and :class:`~snac_gym.common.progress.ProgressLines` writes lines such as
    ``evaluate: 500/1000 rollouts (50 %), 12.3 s, matching effort: lqr`` to stderr, every 10 %
    of the rollouts or 10 s, whichever comes first. ``enabled=False`` (``--no-progress``) writes
    neither.

    Args:
        total: Rollouts expected (grows with :meth:`add_total`).
        enabled: Show progress at all.
        lines: Write plain lines; ``None``: where stderr is not a terminal.
        write: Where the plain lines go (default: one line on stderr, flushed).
        label: Start of each plain line.
    """

    def __init__(
        self,
        total: int,
        enabled: bool,
        lines: bool | None = None,
        write: Callable[[str], None] | None = None,
        label: str = "evaluate:",
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
        """Close the bar."""
        self._bar.close()


__all__ = ["Progress"]
