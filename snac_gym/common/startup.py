"""A command's start-up without the cyclic garbage collector walking its imports.

A command imports NumPy, SciPy, pandas, Pinocchio, numba and the project: hundreds of thousands of objects that
live as long as the process. The collector runs on allocation counts, and each of its full passes walks every
tracked object, so while the imports build them it walks them over and over: 0.26 of the 1.93 CPU seconds of a
4-sample ``snac-gym evaluate``, a sixth of the start-up of a command that loads torch. :func:`pause` stops the
collector for the start-up; :func:`imports_done` freezes what the imports built (``gc.freeze``: later passes skip
those objects, and a forked worker's collector does not touch, and so copy, the pages it inherits) and starts it
again. Both act only for a process whose start-up paused the collector (the console script's): a library call
leaves the caller's collector as it found it.
"""

from __future__ import annotations

import gc

__all__ = ["imports_done", "pause"]

_paused = False


def pause() -> None:
    """Stop the cyclic collector until :func:`imports_done`, if it runs (reference counting still frees at once)."""
    global _paused
    if gc.isenabled():
        gc.disable()
        _paused = True


def imports_done() -> None:
    """Freeze every object built so far and restart the collector that :func:`pause` stopped; otherwise nothing.

    Called where a command's own imports end; once is enough, and a second call does nothing."""
    global _paused
    if _paused:
        _paused = False
        gc.freeze()
        gc.enable()
