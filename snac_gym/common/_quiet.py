"""Silencing C extensions that write straight to the process's stdout/stderr."""

from __future__ import annotations

import contextlib
import os
import sys
from typing import Iterator


@contextlib.contextmanager
def quiet_output() -> Iterator[None]:
    """Silence C-level stdout and stderr (PyBullet prints its build time on import and the options of a client it
    connects, ur_rtde prints socket errors before raising).

    The process's file descriptors 1 and 2 are what C code writes to, whatever ``sys.stdout`` is now (a test's capture,
    a notebook's stream): those are silenced, after Python's own streams are flushed into them.
    """
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, OSError, ValueError):  # None, closed or without a flush
            stream.flush()
    saved: list[tuple[int, int]] = []
    try:
        for fd in (1, 2):
            saved.append((fd, os.dup(fd)))
    except OSError:  # a descriptor closed (a daemon's): nothing to silence there
        for _, copy in saved:
            os.close(copy)
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd, _ in saved:
            os.dup2(devnull, fd)
        yield
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
        os.close(devnull)
