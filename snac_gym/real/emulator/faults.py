"""The faults a test or ``snac-gym emulate-ur``'s flags inject into the emulated controller.

A layer of :class:`~snac_gym.real.emulator.controller.UREmulator` (see :mod:`~snac_gym.real.emulator.state`):
protective and emergency stops, stalls, a dropped link, stale or non-finite state, the watchdog's expiry, each
now or scheduled after the first ``speedJ``, and back to normal.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from snac_gym.real.emulator import protocol as p
from snac_gym.real.emulator.listeners import close_quietly
from snac_gym.real.emulator.registers import Registers

__all__ = ["Faults"]


class Faults(Registers):
    """The injected faults, and the safety state's release."""

    def _release_safety(self) -> None:
        self.safety_bits = 1 << p.SAFETY_NORMAL
        self.safety_mode = p.SAFETY_MODE_NORMAL
        self._stopped_since = None
        if self.runtime_state == p.RUNTIME_PAUSED:  # the program does not resume: the host re-uploads it
            self.runtime_state = p.RUNTIME_STOPPED

    # ----------------------------------------------------------------- faults
    def protective_stop(self) -> None:
        """Protective stop: the arm halts at once, the program pauses, bit 2 of ``safety_status_bits``."""
        with self.lock:
            self.safety_bits = 1 << p.SAFETY_PROTECTIVE_STOPPED
            self.safety_mode = p.SAFETY_MODE_PROTECTIVE_STOP
            self._protective_stop_at = time.monotonic()
            self._halt(p.RUNTIME_PAUSED, "protective stop")

    def emergency_stop(self) -> None:
        """Emergency stop: the arm halts at once, the program stops, bits 5 and 7."""
        with self.lock:
            self.safety_bits = (1 << p.SAFETY_EMERGENCY_STOPPED) | (1 << p.SAFETY_SYSTEM_EMERGENCY_STOPPED)
            self.safety_mode = p.SAFETY_MODE_SYSTEM_EMERGENCY_STOP
            self._halt(p.RUNTIME_STOPPED, "emergency stop")

    def _halt(self, runtime_state: int, what: str) -> None:
        self.arm.move_target = None
        self.arm.qd[:] = 0.0  # a category 0/1 stop: treated as immediate at this time scale
        self.arm.speed_target[:] = 0.0
        if self.runtime_state != p.RUNTIME_STOPPED:
            self.runtime_state = runtime_state
        self._watchdog = None
        self.event(what)

    def clear_faults(self) -> None:
        """Back to normal: safety cleared, stale data and stalls over, connections accepted."""
        with self.lock:
            self._release_safety()
            self._stale, self._stall_until, self._refuse_until = None, 0.0, 0.0
            if self._link_down:
                self._restore_link()
            self.event("faults cleared")

    def latency_spike(self, seconds: float) -> None:
        """The controller stalls for ``seconds``: no data sent, no input served (the arm keeps moving)."""
        _FAULT_ARGUMENTS["latency_spike"](seconds)
        with self.lock:
            self._stall_until = time.monotonic() + seconds
            self.event(f"latency spike of {seconds * 1e3:.0f} ms")

    def drop_connection(self, refuse_for: float = float("inf")) -> None:
        """Cut every client connection and refuse new ones for ``refuse_for`` s (default: until cleared).

        The servers close their sockets (the clients read end of file) and stop listening (a
        reconnect is refused), as when the controller's network goes down.
        """
        _FAULT_ARGUMENTS["drop_connection"](refuse_for)
        with self.lock:
            self._refuse_until = time.monotonic() + min(refuse_for, 1e9)
            self._link_down = True
            for listener in self._listeners:  # new connections are refused
                close_quietly(listener)
            for conn in list(self._connections):
                conn.close()
            for sock in self._sockets:
                close_quietly(sock)
            self._sockets.clear()
            self.event("connections dropped")

    def stale_data(self, on: bool = True) -> None:
        """Freeze the reported timestamp and joint state (the packages keep coming, unchanged)."""
        with self.lock:
            self._stale = None
            if on:
                frozen = self.state_values()
                self._stale = {k: frozen[k] for k in ("timestamp", "actual_q", "actual_qd", "actual_TCP_pose")}
            self.event(f"stale data {'on' if on else 'off'}")

    def nonfinite_state(self, on: bool = True) -> None:
        """Report NaN joint angles (a corrupted package), or stop doing so."""
        with self.lock:
            self._stale = {"actual_q": [float("nan")] * 6} if on else None
            self.event(f"non-finite state {'on' if on else 'off'}")

    def expire_watchdog(self) -> None:
        """Make the RTDE watchdog fire at the next cycle, as if the host had gone silent.

        Raises:
            ValueError: If no watchdog is armed (``setWatchdog`` not called since the program started).
        """
        with self.lock:
            if self._watchdog is None:
                raise ValueError(
                    f"no RTDE watchdog is armed (program running: {self.runtime_state == p.RUNTIME_PLAYING})"
                )
            self._watch_update = -1e9
            self.event("watchdog expiry injected")

    def schedule(self, after_first_speed_command: float, fault: str, *args: Any) -> None:
        """Inject ``fault`` (a method name above) that long after the first ``speedJ``."""
        if not callable(getattr(self, fault, None)) or fault.startswith("_"):
            raise ValueError(f"unknown fault {fault!r}")
        _check_duration("fault time", after_first_speed_command)
        check = _FAULT_ARGUMENTS.get(fault)
        if check is not None:  # refused now, not when the fault comes due inside the control cycle
            check(*args)
        self._scheduled.append((after_first_speed_command, fault, args))

    def _run_scheduled(self, now: float) -> None:
        if self.first_speed_command is None or not self._scheduled:
            return
        due = [s for s in self._scheduled if now - self.first_speed_command >= s[0]]
        self._scheduled = [s for s in self._scheduled if s not in due]
        for _, fault, args in due:
            getattr(self, fault)(*args)


def _check_duration(name: str, seconds: float, allow_inf: bool = False) -> None:
    ok = isinstance(seconds, (int, float)) and seconds >= 0 and (allow_inf or np.isfinite(seconds))
    if not ok or np.isnan(seconds):
        raise ValueError(f"{name} must be a non-negative number of seconds, got {seconds!r}")


#: The argument checks of the faults that take arguments: run by each fault, and before, when it is scheduled.
_FAULT_ARGUMENTS: dict[str, Any] = {
    "latency_spike": lambda seconds: _check_duration("latency spike", seconds),
    "drop_connection": lambda refuse_for=float("inf"): _check_duration("refuse_for", refuse_for, allow_inf=True),
}
