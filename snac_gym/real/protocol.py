"""What every connection to the arm follows (:mod:`snac_gym.real.connections`): the protocol the real-robot env
drives, the safety states a connection reports, and the wall-clock wait that ends a control period."""

from __future__ import annotations

import time
from typing import Protocol, runtime_checkable

import numpy as np

from snac_gym.model.kinematics import Kinematics

__all__ = ["EMERGENCY_STOP", "NORMAL", "PROTECTIVE_STOP", "PROTECTIVE_STOP_LOCKOUT", "ArmConnection", "wait_until"]

#: Safety states a connection reports (``info["safety_state"]`` of the real env).
NORMAL = "normal"
PROTECTIVE_STOP = "protective_stop"
EMERGENCY_STOP = "emergency_stop"
#: Seconds after a protective stop before PolyScope lets it be unlocked (pendant or dashboard).
PROTECTIVE_STOP_LOCKOUT = 5.0


def wait_until(deadline: float, spin: float = 5e-4) -> None:
    """Block until ``time.perf_counter()`` reaches ``deadline``: sleep, then spin the last ``spin`` s.

    A plain ``sleep`` overshoots by a few hundred µs on a general-purpose kernel, which would make
    a rehearsed 8 ms loop run 2 % slow; ur_rtde's ``waitPeriod`` spins for the same reason.
    """
    remaining = deadline - time.perf_counter()
    if remaining > spin:
        time.sleep(remaining - spin)
    while time.perf_counter() < deadline:
        pass


@runtime_checkable
class ArmConnection(Protocol):
    """What the real-robot env needs from an arm."""

    kinematics: Kinematics
    dt: float

    def read_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured joint positions (rad) and velocities (rad/s)."""

    def start_period(self) -> float:
        """Mark the start of a control period; returns its start time (connection clock, s)."""

    def command(self, velocities: np.ndarray) -> None:
        """Send joint-velocity command u (rad/s) for this period (which also feeds the watchdog)."""

    def end_period(self, period_start: float) -> None:
        """Block until the period that began at ``period_start`` is over."""

    def state_timestamp(self) -> float:
        """The controller's time stamp (s) of the state last read: a stale state repeats it."""

    def stop(self) -> None:
        """Decelerate the arm and return once it is at rest; safe to call repeatedly."""

    def move_to(self, q: np.ndarray) -> None:
        """Bring the arm to ``q`` at rest before an episode (slow joint move on hardware)."""

    def safety_state(self) -> str:
        """One of :data:`NORMAL`, :data:`PROTECTIVE_STOP`, :data:`EMERGENCY_STOP`."""

    def close(self) -> None:
        """Stop the arm and release the connection."""
