"""Silencing C extensions that write straight to the process's stdout/stderr."""

from __future__ import annotations

import contextlib
import os
import sys

from snac_gym.common._signals import uninterruptible


class quiet_output:  # noqa: N801 - a context manager used as a function: ``with quiet_output():``
    """Silence C-level stdout and stderr (PyBullet prints its build time on import and the options of a client it
    connects, ur_rtde prints socket errors before raising).

    The process's file descriptors 1 and 2 are what C code writes to, whatever ``sys.stdout`` is now (a test's capture,
    a notebook's stream): those are silenced, after Python's own streams are flushed into them. A stop signal
    (:mod:`snac_gym.common._signals`) never lands between the swaps of the two, nor in ``__enter__`` after them or in
    ``__exit__`` before them: one that left descriptor 2 on ``/dev/null`` would take with it the line in which the
    command says what the signal ended. (A generator-based context manager cannot promise that: a signal handled at
    the first instruction of contextlib's ``__exit__``, as one pending after a slow C call in the block is, skips the
    generator's ``finally`` until the generator is collected.)
    """

    def __init__(self) -> None:
        self._saved: list[int] = []  # [copy of 1, copy of 2, /dev/null], as far as made

    @uninterruptible
    def __enter__(self) -> None:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(AttributeError, OSError, ValueError):  # None, closed or without a flush
                stream.flush()
        _silence(self._saved)

    @uninterruptible
    def __exit__(self, *exc_info: object) -> None:
        _give_back(self._saved)
        self._saved = []


def _silence(saved: list[int]) -> None:
    """Point descriptors 1 and 2 at ``/dev/null``, recording in ``saved`` what :func:`_give_back` undoes (called from
    ``quiet_output.__enter__``, which no stop signal cuts)."""
    try:
        for fd in (1, 2):
            saved.append(os.dup(fd))
    except OSError:  # a descriptor closed (a daemon's): nothing to silence there (_give_back closes the copy made)
        return
    saved.append(os.open(os.devnull, os.O_WRONLY))
    for fd in (1, 2):
        os.dup2(saved[2], fd)


def _give_back(saved: list[int]) -> None:
    """Descriptors 1 and 2 as they were before :func:`_silence`; its copies closed (called from
    ``quiet_output.__exit__``, which no stop signal cuts)."""
    if len(saved) < 3:  # silenced nothing, or cut before it opened /dev/null (then it duplicated 1 and 2 only)
        for copy in saved:
            os.close(copy)
        return
    for fd, copy in zip((1, 2), saved[:2], strict=True):
        os.dup2(copy, fd)
    for copy in saved:
        os.close(copy)
