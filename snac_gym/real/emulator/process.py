"""The emulator in a child process, driven from the parent (tests) through JSON lines.

ur_rtde's Python bindings hold the GIL while they block (the constructors wait for the
controller's replies, ``speedJ`` spins on the script's ready register), so a controller
emulated by threads of the same interpreter would never answer. The emulator therefore runs
in its own process (``python -m snac_gym.real.emulator.process``); :class:`EmulatorProcess`
starts it, forwards fault injections and queries over its stdin/stdout, and stops it on exit.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from typing import Any

import numpy as np
from typing_extensions import Self

from snac_gym.real.emulator.controller import UREmulator

#: Methods of :class:`~snac_gym.real.emulator.controller.UREmulator` the parent may call.
REMOTE_METHODS = frozenset(
    {
        "protective_stop",
        "emergency_stop",
        "clear_faults",
        "latency_spike",
        "drop_connection",
        "stale_data",
        "nonfinite_state",
        "expire_watchdog",
        "set_speed_scaling",
        "set_tcp_offset",
        "schedule",
        "status",
        "speed_commands_after",
        "commands_since",
        "reset",
    }
)


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, float) and not np.isfinite(value):
        return repr(value)
    return value


def _serve(stdin: Any, stdout: Any) -> None:
    """Child side: build the emulator from the first line, then answer one call per line."""

    def reply(status: str, payload: Any) -> None:
        stdout.write(json.dumps([status, payload], default=_plain) + "\n")
        stdout.flush()

    try:
        emulator = UREmulator(**json.loads(stdin.readline())).start()
    except Exception as exc:  # noqa: BLE001 - report why it could not start, then leave
        reply("error", f"{type(exc).__name__}: {exc}")
        return
    reply("ok", emulator.ports)
    try:
        for line in stdin:
            name, args = json.loads(line)
            if name not in REMOTE_METHODS:
                reply("error", f"no remote method {name!r}")
                continue
            args = [float(a) if a in ("inf", "nan") else a for a in args]
            try:
                reply("ok", getattr(emulator, name)(*args))
            except Exception as exc:  # noqa: BLE001 - a bad argument: the parent raises it
                reply("error", f"{type(exc).__name__}: {exc}")
    finally:
        emulator.close()


class EmulatorProcess:
    """An emulated UR controller in a child process; a context manager.

    Keyword arguments are those of :class:`~snac_gym.real.emulator.controller.UREmulator`
    (plain values). Every method of :data:`REMOTE_METHODS` runs in the child, e.g.
    ``emu.protective_stop()`` or ``emu.status()``.

    Raises:
        RuntimeError: If the child cannot start the emulator (e.g. its ports stay busy).
    """

    def __init__(self, start_timeout: float = 60.0, **kwargs: Any) -> None:
        self.kwargs = {k: _plain(v) for k, v in kwargs.items()}
        self.start_timeout = start_timeout
        self._child: subprocess.Popen[str] | None = None
        self._lock = threading.Lock()
        self.ports: dict[str, int] = {}

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> Self:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self._child = subprocess.Popen(
            [sys.executable, "-m", "snac_gym.real.emulator.process"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )
        timer = threading.Timer(self.start_timeout, self._child.kill)
        timer.start()
        try:
            status, payload = self._exchange(self.kwargs)
        except RuntimeError:
            self.close()
            raise RuntimeError(f"the emulator did not start within {self.start_timeout:g} s") from None
        finally:
            timer.cancel()
        if status != "ok":
            self.close()
            raise RuntimeError(f"the emulator could not start: {payload}")
        self.ports = payload
        return self

    def _exchange(self, message: Any) -> tuple[str, Any]:
        if self._child is None or self._child.poll() is not None:
            raise RuntimeError("the emulator process is not running")
        with self._lock:
            self._child.stdin.write(json.dumps(message, default=_plain) + "\n")  # type: ignore[union-attr]
            self._child.stdin.flush()  # type: ignore[union-attr]
            line = self._child.stdout.readline()  # type: ignore[union-attr]
        if not line:
            raise RuntimeError("the emulator process ended")
        status, payload = json.loads(line)
        return status, payload

    def call(self, name: str, *args: Any) -> Any:
        """Call ``name(*args)`` on the emulator in the child and return its result.

        Raises:
            AttributeError: If ``name`` is not a remote method.
            ValueError: If the emulator refused the call (a bad argument).
        """
        if name not in REMOTE_METHODS:
            raise AttributeError(f"the emulator has no remote method {name!r}")
        status, payload = self._exchange([name, list(args)])
        if status != "ok":
            raise ValueError(payload)
        return payload

    def __getattr__(self, name: str) -> Any:
        if name in REMOTE_METHODS:
            return lambda *args: self.call(name, *args)
        raise AttributeError(name)

    def close(self) -> None:
        """Stop the emulator (closing its ports) and reap the child."""
        child, self._child = self._child, None
        if child is None:
            return
        try:
            child.stdin.close()  # type: ignore[union-attr]
        except OSError:
            pass
        try:
            child.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait(timeout=5.0)
        if child.stdout is not None:
            child.stdout.close()


if __name__ == "__main__":
    _serve(sys.stdin, sys.stdout)
