"""The real run's log as it streams: one CSV row per control period, on disk within a second.

The full log (``*_log.parquet``) is written when the episode ends, however it ends; this file is
what is left if the host process itself dies (SIGKILL, out of memory, power): the rows up to the
last flush, at most one second old. Its ``monotonic_s`` column is ``time.monotonic()``, the
system-wide clock that controller-side logs (the emulator's) can be matched against.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

#: Seconds between flushes to the operating system (and so the most a dead host process loses).
FLUSH_EVERY = 1.0


class StepJournal:
    """Appends one row per period to ``path``; flushes every :data:`FLUSH_EVERY` s.

    The flush is one ``write`` from the control loop (tens of µs); the ``fsync`` that takes it to
    the disk runs in a helper thread, since it can take milliseconds and would make a period late.
    """

    def __init__(self, path: Path, n_joints: int) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.rows = 0
        self._file = path.open("w", buffering=1 << 20)
        joints = range(n_joints)
        columns = ["step", "t", "monotonic_s", "period_ms"]
        columns += [f"q_{j}" for j in joints] + [f"qdot_{j}" for j in joints] + ["x_0", "x_1", "x_2"]
        columns += [f"u_{j}" for j in joints] + ["safety_state", "safety"]
        self._file.write(",".join(columns) + "\n")
        self._file.flush()
        self._last_flush = time.perf_counter()
        self._sync = threading.Event()
        self._closed = False
        self._syncer = threading.Thread(target=self._sync_loop, name="journal-fsync", daemon=True)
        self._syncer.start()

    def record(
        self, step: int, t: float, period: float | None, obs: Any, n_joints: int, command: Any, state: str, safety: Any
    ) -> None:
        """One row: the state read at the end of period ``step`` and the command sent in it."""
        if self._closed:
            return
        now = time.perf_counter()
        q_qdot_x = np.asarray(obs)[: 2 * n_joints + 3]
        u = "," * (n_joints - 1) if command is None else ",".join(f"{v:.9g}" for v in command)
        reason = "" if safety is None else '"' + str(safety).replace('"', "'") + '"'
        numbers = ",".join(f"{v:.9g}" for v in q_qdot_x)
        period_ms = "" if period is None else f"{period * 1e3:.4f}"
        self._file.write(f"{step},{t:.6f},{time.monotonic():.6f},{period_ms},{numbers},{u},{state},{reason}\n")
        self.rows += 1
        if now - self._last_flush >= FLUSH_EVERY:
            self.flush(now)

    def flush(self, now: float | None = None) -> None:
        if self._closed:
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
        if self._closed:
            return
        self._file.flush()
        self._closed = True
        self._sync.set()
        self._syncer.join(timeout=1.0)
        try:
            os.fsync(self._file.fileno())
        except OSError:
            pass
        self._file.close()
