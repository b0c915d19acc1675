"""The stream log's writer process (:class:`~snac_gym.real.journal.StepJournal`, ``writer="process"``).

Run as a script (``python -I journal_writer.py PATH JOINTS FLUSH_EVERY``), it imports only the
standard library: it starts in tens of milliseconds and takes no CPU from the loop's first
periods. Rows come on stdin as frames (a 4-byte little-endian length, the row's numbers as
doubles, then the safety state and reason, NUL-separated); they go to PATH, flushed and synced
every FLUSH_EVERY s and at the end of input (the host closed the pipe, or died).
"""

from __future__ import annotations

import os
import select
import struct
import sys
import time
from typing import Any, TextIO

#: Frame header on the pipe: the length of the row that follows.
FRAME = struct.Struct("<I")


def columns(n_joints: int) -> list[str]:
    joints = range(n_joints)
    names = ["step", "t", "monotonic_s", "period_ms"]
    names += [f"q_{j}" for j in joints] + [f"qdot_{j}" for j in joints] + ["x_0", "x_1", "x_2"]
    return names + [f"u_{j}" for j in joints] + ["safety_state", "safety"]


def row_numbers(n_joints: int) -> struct.Struct:
    """step, t, monotonic, period (s; NaN: none), q, q̇, x, u (NaN: none)."""
    return struct.Struct(f"<{4 + 3 * n_joints + 3}d")


def format_row(
    step: int,
    t: float,
    monotonic: float,
    period: float | None,
    numbers: Any,
    n_joints: int,
    command: Any,
    state: str,
    safety: Any,
) -> str:
    u = "," * (n_joints - 1) if command is None else ",".join(f"{v:.9g}" for v in command)
    reason = "" if safety is None else '"' + str(safety).replace('"', "'") + '"'
    values = ",".join(f"{v:.9g}" for v in numbers)
    period_ms = "" if period is None else f"{period * 1e3:.4f}"
    return f"{step},{t:.6f},{monotonic:.6f},{period_ms},{values},{u},{state},{reason}\n"


def serve_writer() -> None:
    """The process writer: rows from stdin to the CSV until end of input (``argv``: path, joints, flush period)."""
    path, n_joints, flush_every = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    try:  # started by a real-time loop, it inherited SCHED_FIFO: the log must never compete with the loop
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass
    numbers = row_numbers(n_joints)
    source = sys.stdin.buffer.fileno()
    with open(path, "a", buffering=1 << 20) as out:
        buffer, last_flush, ended = b"", time.monotonic(), False
        while not ended:
            ready = select.select([source], [], [], flush_every)[0]
            if ready:
                chunk = os.read(source, 1 << 16)
                ended = not chunk
                buffer = _write_frames(out, buffer + chunk, numbers, n_joints)
            if ended or time.monotonic() - last_flush >= flush_every:
                _sync(out)
                last_flush = time.monotonic()


def _write_frames(out: TextIO, buffer: bytes, numbers: struct.Struct, n_joints: int) -> bytes:
    """Write every whole frame of ``buffer`` as a row; return the incomplete rest."""
    while len(buffer) >= FRAME.size:
        size = FRAME.unpack_from(buffer)[0]
        if len(buffer) < FRAME.size + size:
            break
        frame, buffer = buffer[FRAME.size : FRAME.size + size], buffer[FRAME.size + size :]
        values = numbers.unpack_from(frame)
        state, _, safety = frame[numbers.size :].decode().partition("\0")
        step, t, monotonic, period = values[:4]
        command = values[4 + 2 * n_joints + 3 :]
        out.write(format_row(
            int(step), t, monotonic, None if period != period else period, values[4 : 4 + 2 * n_joints + 3],
            n_joints, None if command[0] != command[0] else command, state, safety or None,
        ))  # fmt: skip
    return buffer


def _sync(out: TextIO) -> None:
    out.flush()
    try:
        os.fsync(out.fileno())
    except OSError:
        pass


if __name__ == "__main__":
    serve_writer()
