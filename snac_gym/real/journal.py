"""The real run's log as it streams: one CSV row per control period, on disk within a second.

The full log (``*_log.parquet``) is written when the episode ends, however it ends; this file is
what is left if the host process itself dies (SIGKILL, out of memory, power): the rows up to the
last flush, at most one second old. Its ``monotonic_s`` column is ``time.monotonic()``, the
system-wide clock that controller-side logs (the emulator's) can be matched against.

Two writers, the same file: ``"process"`` (the default) hands each row's numbers, packed, to a
writer process over a pipe (one ``write`` of a few hundred bytes in the loop; the formatting,
the flushes and the ``fsync`` happen in the other process, so they hold neither the loop's CPU
time nor its interpreter lock); ``"inline"`` formats and buffers each row in the loop and
flushes from it every :data:`FLUSH_EVERY` s (the ``fsync`` in a helper thread). With the
process writer a host killed outright loses nothing that reached the pipe: the writer reads to
the end, writes it, and exits.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from snac_gym.real import journal_writer
from snac_gym.real.journal_writer import FRAME, columns, format_row

#: Seconds between flushes to the operating system (and so the most a dead host process loses).
FLUSH_EVERY = 1.0
JOURNAL_WRITERS = ("process", "inline")


class StepJournal:
    """Appends one row per period to ``path``; on disk within :data:`FLUSH_EVERY` s.

    Args:
        path: The CSV file.
        n_joints: Joints of the arm (the row's layout).
        writer: ``"process"`` or ``"inline"`` (see the module docs).

    Raises:
        ValueError: On an unknown ``writer``.
    """

    def __init__(self, path: Path, n_joints: int, writer: str = "process") -> None:
        if writer not in JOURNAL_WRITERS:
            raise ValueError(f"writer must be one of {list(JOURNAL_WRITERS)}, got {writer!r}")
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.writer = writer
        self.rows = 0
        self._n_joints = n_joints
        self._closed = False
        self._numbers = journal_writer.row_numbers(n_joints)
        path.write_text(",".join(columns(n_joints)) + "\n")  # the header is on disk before the first period
        if writer == "process":
            self._process = subprocess.Popen(
                [sys.executable, "-I", journal_writer.__file__, str(path), str(n_joints), repr(FLUSH_EVERY)],
                stdin=subprocess.PIPE, start_new_session=True,  # a Ctrl-C reaches the run, which closes the pipe
            )  # fmt: skip
            self._pipe = self._process.stdin.fileno()  # type: ignore[union-attr]
            return
        self._file = path.open("a", buffering=1 << 20)
        self._last_flush = time.perf_counter()
        self._sync = threading.Event()
        self._syncer = threading.Thread(target=self._sync_loop, name="journal-fsync", daemon=True)
        self._syncer.start()

    def record(
        self, step: int, t: float, period: float | None, obs: Any, n_joints: int, command: Any, state: str, safety: Any
    ) -> None:
        """One row: the state read at the end of period ``step`` and the command sent in it."""
        if self._closed:
            return
        numbers = np.asarray(obs)[: 2 * n_joints + 3]
        if self.writer == "process":
            u = (np.nan,) * n_joints if command is None else command
            text = (state + "\0" + ("" if safety is None else str(safety))).encode()
            nan = float("nan")
            payload = self._numbers.pack(step, t, time.monotonic(), nan if period is None else period, *numbers, *u)
            try:
                os.write(self._pipe, FRAME.pack(len(payload) + len(text)) + payload + text)
            except OSError:  # the writer died: the full log is still written at the end
                self._closed = True
            self.rows += 1
            return
        now = time.perf_counter()
        self._file.write(format_row(step, t, time.monotonic(), period, numbers, n_joints, command, state, safety))
        self.rows += 1
        if now - self._last_flush >= FLUSH_EVERY:
            self.flush(now)

    def flush(self, now: float | None = None) -> None:
        if self._closed or self.writer == "process":  # the writer process flushes on its own clock
            return
        self._file.flush()
        self._last_flush = time.perf_counter() if now is None else now
        self._sync.set()

    def _sync_loop(self) -> None:
        while True:
            self._sync.wait()
            self._sync.clear()
            if self._closed:
                return
            try:
                os.fsync(self._file.fileno())
            except (OSError, ValueError):  # closed meanwhile
                return

    def close(self) -> None:
        if self._closed and self.writer == "inline":
            return
        self._closed = True
        if self.writer == "process":
            try:
                self._process.stdin.close()  # type: ignore[union-attr]
            except OSError:
                pass
            try:
                self._process.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
            return
        self._file.flush()
        self._sync.set()
        self._syncer.join(timeout=1.0)
        try:
            os.fsync(self._file.fileno())
        except OSError:
            pass
        self._file.close()
