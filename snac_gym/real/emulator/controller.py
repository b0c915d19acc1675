"""The emulated UR controller: state, control cycle, faults, and the servers ur_rtde talks to.

The class is built in layers, one concern each, every layer on the one beneath:
:mod:`~snac_gym.real.emulator.state` (what the controller holds and reports), :mod:`~snac_gym.real.emulator.listeners`
(sockets and threads), :mod:`~snac_gym.real.emulator.registers` (the RTDE inputs and outputs),
:mod:`~snac_gym.real.emulator.faults` (what tests inject), :mod:`~snac_gym.real.emulator.dashboard` (the dashboard's
answers); this module adds the control cycle, the programs and the queries for tests, and re-exports the layers'
public names.
"""

from __future__ import annotations

import logging
import os
import re
import time
from typing import Any

import numpy as np

from snac_gym.real.emulator import protocol as p
from snac_gym.real.emulator.arm import EmulatedArm
from snac_gym.real.emulator.dashboard import UNLOCK_TOO_EARLY, DashboardAnswers
from snac_gym.real.emulator.registers import MOTION_COMMANDS
from snac_gym.real.emulator.script import ControlScript
from snac_gym.real.emulator.servers import RTDEConnection
from snac_gym.real.emulator.state import (
    PORT_OFFSETS,
    STANDARD_PORT_BASE,
    STOP_DECELERATION,
    VERSIONS,
    ReceivedCommand,
    log,
)
from snac_gym.sampling import nominal_configuration

__all__ = [
    "MOTION_COMMANDS",
    "PORT_OFFSETS",
    "STANDARD_PORT_BASE",
    "STOP_DECELERATION",
    "UNLOCK_TOO_EARLY",
    "VERSIONS",
    "ReceivedCommand",
    "UREmulator",
    "log",
]

#: The events that record a controller stop (``status()["safety_stop_at"]``).
_SAFETY_STOPS = ("protective stop", "emergency stop")


class UREmulator(DashboardAnswers):
    """A UR controller on the loopback interface that ur_rtde's interfaces connect to and drive.

    Serves RTDE (output/input recipes, start/pause, data at 125 Hz (``series="cb"``) or 500 Hz
    (``"e"``)), the dashboard, and the script ports; runs ur_rtde's uploaded control script's
    register handshake; and integrates the arm in real time. Faults are injected with the methods
    below, from a test or from ``snac-gym emulate-ur``'s flags.

    ur_rtde connects to the fixed ports 29999, 30003 and 30004 (``RTDEControlInterface`` takes
    no port), so the default ``port_base=29999`` is the one ur_rtde can use; ``port_base=0``
    binds every server to a free port (see :attr:`ports`) for clients that take ports. While
    another emulator holds the standard ports, ``start`` waits up to ``bind_timeout`` s.

    Args:
        robot: Arm model (UR DH table and the start pose's velocity limits).
        series: ``"cb"`` or ``"e"``; ``None``: the arm's own.
        host: Loopback address to listen on (only ``127.x.x.x`` is accepted).
        port_base: Dashboard port; the others follow at the standard offsets.
        q0: Initial joint angles (default: the nominal elbow-up pose).
        speed_scaling: Speed slider fraction in (0, 1].
        tcp_offset: TCP offset ``[x, y, z, rx, ry, rz]`` applied to ``actual_TCP_pose``.
        bind_timeout: Seconds to wait for busy ports.
        rt_priority: ``SCHED_FIFO`` priority of the control cycle's thread and the servers'
            (0: normal scheduling), so that on a busy host the cycle keeps its rate, as a real
            controller's does; needs
            the right to set it (root or ``CAP_SYS_NICE``), else it runs at normal priority.

    Raises:
        ValueError: On a bad argument.
    """

    # ----------------------------------------------------------------- control cycle
    def _control_loop(self) -> None:
        if self.rt_priority:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.rt_priority))
            except (PermissionError, OSError, AttributeError) as exc:
                self.event(f"real-time priority not set ({exc}): the cycle runs at normal priority")
        next_time = time.perf_counter()
        while not self._stop.is_set():
            next_time += self.dt
            self._control_cycle()
            delay = next_time - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.1:  # far behind (a stalled host): drop the backlog, keep the rate
                next_time = time.perf_counter()

    def _control_cycle(self) -> None:
        now = time.monotonic()
        with self.lock:
            self._run_scheduled(now)
            if self._link_down and now >= self._refuse_until:
                self._restore_link()
            stalled = now < self._stall_until
            if not stalled and self.script is not None and self.runtime_state == p.RUNTIME_PLAYING:
                self.script.cycle(self.inputs)
                if not self.script.running:
                    self._end_program("the control script ended (stopScript)")
            self._check_watchdog(now)
            self.arm.step(self.dt, self.speed_scaling)
            self.timestamp += self.dt
            self._cycle += 1
            if stalled:
                return
            values = self.state_values()
            due = [c for c in self._connections if c.started and not c.closed and c.output is not None and self._due(c)]
            if due:
                self._awaiting_fresh_state = False
                if self._stopped_since is None and self.safety_bits != 1 << p.SAFETY_NORMAL:
                    self._stopped_since = now
        for conn in due:
            conn.send(conn.output.pack(values))  # type: ignore[union-attr]

    def _due(self, conn: RTDEConnection) -> bool:
        every = max(1, round(self.frequency / conn.frequency))
        return self._cycle % every == 0

    # ----------------------------------------------------------------- programs
    def run_program(self, program: str) -> None:
        """A program arrived on a script port: run it if it is ur_rtde's control script."""
        name = program.split("(", 1)[0][4:].strip()
        with self.lock:
            self.programs.append(name)
            if self.safety_bits != 1 << p.SAFETY_NORMAL:
                self.event(f"program {name} refused: the robot is stopped ({self._safety_name()})")
                return
            if "# HEADER_BEGIN" not in program or "rtde_cmd()" not in program:
                self.event(f"program {name} is not ur_rtde's control script: not run by the emulator")
                return
            match = re.search(r"global reg_offset_int = *(\d+)", program)
            self.script = ControlScript(self, int(match.group(1)) if match else 0)
            self.runtime_state = p.RUNTIME_PLAYING
            self._watchdog = None
            self.event(f"program {name} running (register offset {self.script.offset})")

    def secondary_command(self, line: str) -> None:
        """A one-line script command (not a program): recorded as an event, not run."""
        self.event(f"script line ignored by the emulator: {line[:80]}")

    def on_speed_command(self) -> None:
        if self.first_speed_command is None:
            self.first_speed_command = time.monotonic()

    def set_watchdog(self, min_frequency: float, variable: str) -> None:
        """``rtde_set_watchdog(variable, min_frequency, "stop")``: stop the program if the input goes quiet."""
        if min_frequency > 0:
            self._watchdog = (min_frequency, variable)
            self._watch_update = time.monotonic()
            self.event(f"watchdog set on {variable}: {min_frequency:g} Hz")

    def _check_watchdog(self, now: float) -> None:
        gap, self._last_cycle = now - self._last_cycle, now
        if gap > 3 * self.dt:  # the emulator itself was descheduled: its inputs may still be queued
            self._watch_update += gap - self.dt
        if self._watchdog is None or self.runtime_state != p.RUNTIME_PLAYING:
            return
        if now - self._watch_update > 1.0 / self._watchdog[0]:
            owner = self._input_owner.get(self._watchdog[1])
            if self._link_down:  # the controller's network went down (drop_connection): the watchdog stops the arm
                self._end_program(
                    f"watchdog expired after the link dropped: program stopped {now - self._watch_update:.3f} s "
                    f"after its last command (watchdog period {1.0 / self._watchdog[0]:.3f} s)",
                    logging.WARNING,
                )
            elif owner is None or owner.closed:  # the usual end of a run: not a fault
                self._end_program(
                    f"watchdog expired after the client closed the link (the usual end of a run, not a fault): "
                    f"program stopped {now - self._watch_update:.3f} s after its last command"
                )
            else:
                self._end_program(
                    f"watchdog expired: no update of {self._watchdog[1]} for {now - self._watch_update:.3f} s "
                    "from a connected client (a stalled host)",
                    logging.WARNING,
                )

    # ----------------------------------------------------------------- queries for tests
    def speed_commands_after(self, t: float) -> list[tuple[float, list[float]]]:
        """``(time, joint speeds)`` of the ``speedJ`` packages received after monotonic time ``t``."""
        with self.lock:
            return [
                (c.t, [float(c.values.get(f"input_double_register_{j}", 0.0)) for j in range(6)])
                for c in self.commands
                if c.t > t and c.command == p.SPEEDJ
            ]

    def commands_since(self, t: float) -> list[tuple[float, int, dict[str, Any]]]:
        """``(time, command id, register values)`` of every command package received after monotonic time ``t``."""
        with self.lock:
            return [(c.t, c.command, c.values) for c in self.commands if c.t > t]

    def status(self) -> dict[str, Any]:
        """The controller's state in plain types: arm, program, safety, events, watchdog."""
        with self.lock:
            return {
                "q": self.arm.q.tolist(),
                "qd": self.arm.qd.tolist(),
                "timestamp": self.timestamp,
                "runtime_state": self.runtime_state,
                "program_running": self.runtime_state == p.RUNTIME_PLAYING,
                "safety": self._safety_name(),
                "speed_scaling": self.speed_scaling,
                "events": [text for _, text in self.events],
                # Monotonic time of the last protective or emergency stop (None: none since the reset).
                "safety_stop_at": next((t for t, text in reversed(self.events) if text in _SAFETY_STOPS), None),
                # When the first data package showing a stop was sent: the host cannot know of it before.
                "stop_reported_at": self._stopped_since,
                "programs": list(self.programs),
                "protocol_errors": list(self.protocol_errors),
                "watchdog": self._watchdog,
                "unsupported_commands": list(self.script.unsupported) if self.script else [],
                "unsafe_commands": [text for _, text in self.unsafe_commands],
                "first_speed_command": self.first_speed_command,
                "now": time.monotonic(),
                "tcp_pose": self.arm.tcp_pose(self.tcp_offset).tolist(),
            }

    def reset(self, q0: list[float] | None = None) -> None:
        """Between tests: faults cleared, program stopped, arm at rest at ``q0``, logs emptied."""
        with self.lock:
            self.clear_faults()
            self.runtime_state = p.RUNTIME_STOPPED
            self.script, self._watchdog, self._scheduled = None, None, []
            start = nominal_configuration(self.kinematics) if q0 is None else np.asarray(q0, dtype=float)
            self.arm = EmulatedArm(self.arm.robot, start, self.velocity_limits)
            self.tcp_offset, self.speed_scaling = np.zeros(6), 1.0
            self.commands.clear()
            self.unsafe_commands.clear()
            self.events.clear()
            self.programs.clear()
            self.first_speed_command = None
