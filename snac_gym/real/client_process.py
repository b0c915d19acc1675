"""The ur_rtde client's process (:mod:`snac_gym.real.rtde_client`) seen from the parent: requests with deadlines,
its output, and its end (:class:`~snac_gym.real.connections.URRTDEConnection` talks to the arm through it)."""

from __future__ import annotations

import collections
import os
import pickle
import select
import signal
import subprocess
import sys
import threading
import time
from typing import Any

from snac_gym.common.errors import ConnectionFailure
from snac_gym.real.rtde_client import HEADER, RECONNECT_MARKERS, write_frame

__all__ = ["ClientProcess"]


class ClientProcess:
    """The ur_rtde client's process, seen from the parent: requests with deadlines, and its output.

    :meth:`abandon` (from any thread) records why and kills it; the first reason is kept.
    """

    def __init__(self) -> None:
        self.failure: str | None = None
        self.output: collections.deque[str] = collections.deque(maxlen=50)
        self._lock = threading.Lock()
        self._seq = 0
        self._buffer = b""
        self._process = subprocess.Popen(
            [sys.executable, "-c", "from snac_gym.real.rtde_client import serve; serve()"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            bufsize=0,
            start_new_session=True,  # a Ctrl-C at the terminal reaches the parent only, which stops the arm
        )
        self._reader = threading.Thread(target=self._watch_output, name="ur_rtde-output", daemon=True)
        self._reader.start()

    @property
    def pid(self) -> int:
        return self._process.pid

    def _watch_output(self) -> None:
        for raw in self._process.stderr:  # type: ignore[union-attr]
            line = raw.decode(errors="replace").rstrip()
            if not line:
                continue
            self.output.append(line)
            if any(marker in line.lower() for marker in RECONNECT_MARKERS):
                self.abandon(
                    f"link to the arm lost: ur_rtde began to reconnect by itself ({line.strip()!r}), client ended"
                )

    def abandon(self, reason: str) -> None:
        with self._lock:
            if self.failure is None:
                self.failure = reason
            if self._process.returncode is None:
                try:
                    self._process.kill()
                except OSError:
                    pass

    def call(self, name: str, args: tuple[object, ...], timeout: float) -> tuple[str, Any]:
        """Send one request and wait for its reply, at most ``timeout`` s.

        Raises:
            ConnectionFailure: With the reason, if the client is gone, crashes, or misses the deadline.
        """
        if self.failure is not None:
            raise ConnectionFailure(self.failure)
        self._seq += 1
        seq = self._seq
        try:
            write_frame(self._process.stdin.fileno(), (seq, name, args))  # type: ignore[union-attr]
        except (BrokenPipeError, ValueError, OSError):
            self._ended(name)
        deadline = time.perf_counter() + timeout
        while True:
            frame = self._next_frame(deadline, name, timeout)
            if frame[0] == seq:  # a reply to a request a signal interrupted is dropped
                return frame[1], frame[2]

    def _next_frame(self, deadline: float, name: str, timeout: float) -> tuple[int, str, Any]:
        fd = self._process.stdout.fileno()  # type: ignore[union-attr]
        while True:
            if len(self._buffer) >= HEADER.size:
                size = HEADER.unpack_from(self._buffer)[0] + HEADER.size
                if len(self._buffer) >= size:
                    frame, self._buffer = self._buffer[HEADER.size : size], self._buffer[size:]
                    return pickle.loads(frame)
            remaining = deadline - time.perf_counter()
            if remaining <= 0 or not select.select([fd], [], [], remaining)[0]:
                if self._process.poll() is not None:
                    self._ended(name)
                self.abandon(
                    f"ur_rtde did not return from {name} within {timeout * 1e3:.0f} ms (client killed; "
                    "the controller's watchdog stops the arm)"
                )
                raise ConnectionFailure(self.failure)
            data = os.read(fd, 65536)
            if not data:
                self._ended(name)
            self._buffer += data

    def _ended(self, name: str) -> None:
        """The client's pipe closed: it crashed or was killed. Raises :class:`ConnectionFailure`."""
        try:
            code = self._process.wait(timeout=1.0)
        except Exception:  # noqa: BLE001 - still not gone: kill it below
            code = None
        if code is not None and code < 0:
            how = f"was killed by {signal.Signals(-code).name}"
        else:
            how = f"exited with code {code}"
        last = f" after printing {self.output[-1]!r}" if self.output else ""
        self.abandon(f"the ur_rtde client {how} during {name}{last}")
        raise ConnectionFailure(self.failure)

    def close(self, timeout: float) -> None:
        """Ask the client to disconnect and leave; kill it if it does not within ``timeout`` s."""
        if self.failure is None and timeout > 0:
            try:
                self.call("close", (), timeout)
            except ConnectionFailure:
                pass
        process = self._process
        for stream in (process.stdin, process.stdout):
            try:
                stream.close()  # type: ignore[union-attr]
            except OSError:
                pass
        try:
            process.wait(timeout=max(timeout, 0.1))
        except Exception:  # noqa: BLE001 - it would not leave: kill it
            process.kill()
            process.wait()
        self._reader.join(timeout=1.0)
