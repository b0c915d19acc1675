"""The emulated controller's state: what it holds, what it reports, and its pendant's settings.

The bottom of :class:`~snac_gym.real.emulator.controller.UREmulator`'s layers. Each layer is a class on the
one beneath (state, :mod:`~snac_gym.real.emulator.listeners`, :mod:`~snac_gym.real.emulator.registers`,
:mod:`~snac_gym.real.emulator.faults`, :mod:`~snac_gym.real.emulator.dashboard`, then the controller's cycle and
programs), so that each calls only what is defined beneath it and mypy checks every call; the emulator is one
object still, as the servers, the control script and the tests see it.
"""

from __future__ import annotations

import logging
import re
import socket
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from snac_gym.model.kinematics import Kinematics
from snac_gym.model.ur_models import SERIES_FREQUENCY, series_of, velocity_limits
from snac_gym.real.connections import DASHBOARD_PORT
from snac_gym.real.emulator import protocol as p
from snac_gym.real.emulator.arm import EmulatedArm
from snac_gym.real.emulator.script import ControlScript
from snac_gym.real.emulator.servers import RTDEConnection
from snac_gym.sampling import nominal_configuration

__all__ = ["PORT_OFFSETS", "STANDARD_PORT_BASE", "STOP_DECELERATION", "VERSIONS", "ControllerState", "ReceivedCommand"]

log = logging.getLogger("snac_gym.emulate_ur")

#: Standard ports of a UR controller, as offsets from the dashboard port (29999).
PORT_OFFSETS = {"dashboard": 0, "secondary": 3, "realtime": 4, "rtde": 5}
STANDARD_PORT_BASE = DASHBOARD_PORT
#: Controller versions reported (``getControllerVersion``): CB3 runs 3.x, e-Series 5.x.
VERSIONS = {"cb": (3, 15, 8, 106339), "e": (5, 11, 6, 108805)}
#: The events that record a controller stop (``status()["safety_stop_at"]``).
#: Deceleration of the controller's own stops (program stopped, watchdog), rad/s².
STOP_DECELERATION = 10.0


@dataclass
class ReceivedCommand:
    """A data package from the control client that carried a command register."""

    t: float
    command: int
    values: dict[str, Any]


class ControllerState:
    """The controller's state, its event log, and what it reports of them (safety, program, settings).

    :class:`~snac_gym.real.emulator.controller.UREmulator` describes the arguments.
    """

    def __init__(
        self,
        robot: str = "ur10",
        series: str | None = None,
        host: str = "127.0.0.1",
        port_base: int = STANDARD_PORT_BASE,
        q0: np.ndarray | Sequence[float] | None = None,
        speed_scaling: float = 1.0,
        tcp_offset: np.ndarray | Sequence[float] | None = None,
        bind_timeout: float = 30.0,
        rt_priority: int = 0,
    ) -> None:
        series = series_of(robot, series)
        if not re.fullmatch(r"127\.\d{1,3}\.\d{1,3}\.\d{1,3}", host):
            raise ValueError(f"host must be a loopback address (127.x.x.x), where the emulator listens, got {host!r}")
        if not (port_base == 0 or 1024 <= port_base <= 65535 - max(PORT_OFFSETS.values())):
            raise ValueError(f"port_base must be 0 (free ports) or in [1024, 65530], got {port_base!r}")
        self.kinematics = Kinematics(robot)
        self.series, self.host, self.port_base, self.bind_timeout = series, host, port_base, bind_timeout
        if not (isinstance(rt_priority, int) and 0 <= rt_priority <= 99):
            raise ValueError(f"rt_priority must be a whole number in [0, 99], got {rt_priority!r}")
        self.rt_priority = rt_priority
        self.frequency = SERIES_FREQUENCY[series]
        self.dt = 1.0 / self.frequency
        self.version = VERSIONS[series]
        start = nominal_configuration(self.kinematics) if q0 is None else np.asarray(q0, dtype=float)
        #: Joint speed limits the controller keeps: the URDF's, capped at the model's datasheet.
        self.velocity_limits = velocity_limits(robot, self.kinematics.velocity_limits)
        self.arm = EmulatedArm(robot, start, self.velocity_limits)
        self.tcp_offset = np.zeros(6) if tcp_offset is None else np.asarray(tcp_offset, dtype=float)
        self.set_speed_scaling(speed_scaling)
        self.lock = threading.RLock()
        self.ports: dict[str, int] = {}
        self.script: ControlScript | None = None
        self.runtime_state = p.RUNTIME_STOPPED
        self.safety_bits = 1 << p.SAFETY_NORMAL
        self.safety_mode = p.SAFETY_MODE_NORMAL
        self.timestamp = 0.0
        self.inputs: dict[str, Any] = {}
        self.commands: deque[ReceivedCommand] = deque(maxlen=100_000)
        self.events: list[tuple[float, str]] = []
        self.protocol_errors: list[str] = []
        self.programs: list[str] = []
        self.first_speed_command: float | None = None
        self._watchdog: tuple[float, str] | None = None
        self._watch_update = 0.0
        self._last_cycle = time.monotonic()
        self._stall_until = 0.0
        self._stale: dict[str, Any] | None = None
        self._refuse_until = 0.0
        self._link_down = False
        #: Motion commands that arrived while the controller reported a stop, or after the link came
        #: back before any state package had gone out: what the host must never send (see
        #: :meth:`receive_inputs`). Each: ``(time, what)``.
        self.unsafe_commands: list[tuple[float, str]] = []
        self._stopped_since: float | None = None  # first state package that reported the stop
        self._protective_stop_at = 0.0
        self._awaiting_fresh_state = False
        self._input_owner: dict[str, RTDEConnection] = {}
        self._connections: list[RTDEConnection] = []
        self._sockets: list[socket.socket] = []
        self._listeners: list[socket.socket] = []
        self._threads: list[threading.Thread] = []
        self._scheduled: list[tuple[float, str, tuple[Any, ...]]] = []
        self._stop = threading.Event()
        #: The error that ended one of the emulator's threads (it then stops as a whole), or ``None``.
        self.failure: BaseException | None = None
        self._cycle = 0

    def event(self, text: str, level: int = logging.INFO) -> None:
        """Record (and log, at ``level``: a fault of the host at WARNING) something the controller did."""
        self.events.append((time.monotonic(), text))
        log.log(level, text)

    def _program_state(self) -> str:
        """The dashboard's ``programState`` word: ``PLAYING``, ``PAUSED`` or ``STOPPED`` (the RTDE runtime state)."""
        return {p.RUNTIME_PLAYING: "PLAYING", p.RUNTIME_PAUSED: "PAUSED"}.get(self.runtime_state, "STOPPED")

    def _safety_name(self) -> str:
        if self.safety_bits & (1 << p.SAFETY_EMERGENCY_STOPPED):
            return "SYSTEM_EMERGENCY_STOP"
        if self.safety_bits & (1 << p.SAFETY_PROTECTIVE_STOPPED):
            return "PROTECTIVE_STOP"
        return "NORMAL"

    def _end_program(self, reason: str, level: int = logging.INFO) -> None:
        self.runtime_state = p.RUNTIME_STOPPED
        self.arm.stopj(STOP_DECELERATION)
        self._watchdog = None
        self.event(reason, level)

    def set_speed_scaling(self, fraction: float) -> None:
        """The speed slider: commanded speeds are scaled by ``fraction`` in (0, 1]."""
        if not (isinstance(fraction, (int, float)) and 0.0 < fraction <= 1.0):
            raise ValueError(f"speed scaling must be in (0, 1], got {fraction!r}")
        self.speed_scaling = float(fraction)

    def set_tcp_offset(self, offset: np.ndarray) -> None:
        """Change the TCP offset reported poses include (a wrong tool on the pendant)."""
        offset = np.asarray(offset, dtype=float)
        if offset.shape != (6,) or not np.isfinite(offset).all():
            raise ValueError(f"a TCP offset is 6 finite numbers [x, y, z, rx, ry, rz], got {offset.tolist()}")
        self.tcp_offset = offset
