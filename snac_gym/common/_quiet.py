"""Silencing C extensions that write straight to the process's stdout/stderr."""

from __future__ import annotations

import contextlib
import os
import sys
from typing import Iterator


@contextlib.contextmanager
def quiet_output() -> Iterator[None]:
    """Silence C-level stdout and stderr (PyBullet prints its build time on import,
    ur_rtde prints socket errors before raising)."""
    streams = [sys.stdout, sys.stderr]
    saved: list[tuple[int, int]] = []
    try:
        for stream in streams:
            stream.flush()
            fd = stream.fileno()
            saved.append((fd, os.dup(fd)))
    except (AttributeError, OSError, ValueError):  # captured or fake streams: nothing to silence
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
