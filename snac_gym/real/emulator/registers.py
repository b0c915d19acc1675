"""The emulated controller's RTDE registers: the inputs clients write, the outputs each package carries.

A layer of :class:`~snac_gym.real.emulator.controller.UREmulator` (see :mod:`~snac_gym.real.emulator.state`):
which client owns an input, the command packages recorded (and those the host must not send), and every output
variable's value.
"""

from __future__ import annotations

import time
from typing import Any

from snac_gym.real.emulator import protocol as p
from snac_gym.real.emulator.listeners import Listeners
from snac_gym.real.emulator.script import ControlScript
from snac_gym.real.emulator.servers import RTDEConnection
from snac_gym.real.emulator.state import ReceivedCommand

__all__ = ["MOTION_COMMANDS", "Registers"]

#: Commands that move the arm: none may arrive while the controller reports a stop.
MOTION_COMMANDS = frozenset({p.SPEEDJ, p.MOVEJ})


class Registers(Listeners):
    """The RTDE inputs received and the outputs sent."""

    # ----------------------------------------------------------------- RTDE inputs
    def input_in_use(self, name: str, conn: RTDEConnection) -> bool:
        with self.lock:
            owner = self._input_owner.get(name)
            return owner is not None and owner is not conn and not owner.closed

    def claim_inputs(self, names: list[str], conn: RTDEConnection) -> None:
        with self.lock:
            for name in names:
                self._input_owner[name] = conn

    def release_inputs(self, conn: RTDEConnection) -> None:
        with self.lock:
            self._input_owner = {k: v for k, v in self._input_owner.items() if v is not conn}
            if conn in self._connections:
                self._connections.remove(conn)

    def receive_inputs(self, recipe_id: int, values: dict[str, Any]) -> None:
        """A data package from a client: the registers take its values (the latest wins each cycle)."""
        now = time.monotonic()
        with self.lock:
            self.inputs.update(values)
            if self._watchdog is not None and self._watchdog[1] in values:
                self._watch_update = now
            for name, value in values.items():
                if name.startswith("input_int_register_") and name.endswith(("_0", "_24")):
                    self.commands.append(ReceivedCommand(now, int(value), dict(values)))
                    if int(value) in MOTION_COMMANDS:
                        self._check_motion_command(now, int(value))
                    break

    def _check_motion_command(self, now: float, command: int) -> None:
        """Record a motion command the host should not have sent.

        Either the controller reports a stop (the delay since the first state package that said
        so is kept: a command already in flight then arrives within a period or so), or the link
        came back and no state package has been sent since (the host cannot know where the arm is).
        """
        name = "speedJ" if command == p.SPEEDJ else "moveJ"
        if self.safety_bits != 1 << p.SAFETY_NORMAL:
            since = (
                "before it was reported"
                if self._stopped_since is None
                else (f"{(now - self._stopped_since) * 1e3:.1f} ms after it was reported")
            )
            self.unsafe_commands.append((now, f"{name} during {self._safety_name()} ({since})"))
        elif self._awaiting_fresh_state:
            self.unsafe_commands.append((now, f"{name} after the link came back, before any state package"))

    def state_values(self) -> dict[str, Any]:
        """Every output variable's current value, as the next data package would carry it."""
        q, qd = self.arm.q.tolist(), self.arm.qd.tolist()
        tcp = self.arm.tcp_pose(self.tcp_offset).tolist()
        values: dict[str, Any] = {
            "timestamp": self.timestamp,
            "actual_q": q,
            "actual_qd": qd,
            "target_q": q,
            "target_qd": qd,
            "actual_TCP_pose": tcp,
            "target_TCP_pose": tcp,
            "speed_scaling": self.speed_scaling,
            "target_speed_fraction": self.speed_scaling,
            "runtime_state": self.runtime_state,
            "safety_status_bits": self.safety_bits,
            "safety_mode": self.safety_mode,
            "safety_status": self.safety_mode,
            "robot_mode": p.ROBOT_MODE_RUNNING,
            "robot_status_bits": self._robot_status(),
            "joint_mode": [253] * 6,
            "actual_execution_time": 0.5,
        }
        if self._stale is not None:
            values.update(self._stale)
        return _DefaultValues(values, self.inputs, self.script)

    def _robot_status(self) -> int:
        running = self.runtime_state == p.RUNTIME_PLAYING
        return (1 << p.STATUS_POWER_ON) | (int(running) << p.STATUS_PROGRAM_RUNNING)


class _DefaultValues(dict):
    """Output values, with the registers from the inputs and the script, and zeros for the rest."""

    def __init__(self, values: dict[str, Any], inputs: dict[str, Any], script: ControlScript | None) -> None:
        super().__init__(values)
        self.update(inputs)
        if script is not None:
            self.update(script.register_values())

    def __missing__(self, name: str) -> Any:
        kind = p.output_type(name) or "DOUBLE"
        if kind.startswith("VECTOR"):
            return [0] * int(kind[6])
        return 0.0 if kind == "DOUBLE" else 0
