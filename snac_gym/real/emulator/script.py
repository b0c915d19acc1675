"""ur_rtde's control script (``rtde_control.script``), re-enacted for the emulated controller.

The script's main loop, once per controller cycle (from ``scripts/rtde_control.script`` of
ur_rtde 1.6.5, the ``# NODE_CONTROL_LOOP_BEGINS`` block)::

    signal_ready()                                   # output_int_register_0 = 1
    while keep_running:
        cmd = rtde_cmd()                             # input_int_register_0
        if cmd in REALTIME_COMMANDS:                 # speedJ, servoJ, ...: no handshake
            keep_running = process_cmd(cmd); signal_ready()
        elif cmd == 0:                               # the host's clear command
            executing_cmd = False; signal_ready()
        else:
            if not executing_cmd: keep_running = process_cmd(cmd)   # ends in signal_done_with_cmd()
            executing_cmd = True
        sync()

``process_cmd`` of a blocking command (``movej``, ``stopj``, ``speed_stop``) returns once the
motion is over; here it is a pending motion that the loop waits on before ``signal_done``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from snac_gym.real.emulator import protocol as p

_STOP_TYPES = (p.SPEED_STOP, p.STOPJ, 33)


class ControlScript:
    """The running ``rtde_control`` program: the register handshake and the commands it serves.

    Args:
        controller: The emulated controller (its arm, watchdog and stop actions).
        register_offset: 0, or 24 for ur_rtde's upper register range.
    """

    def __init__(self, controller: Any, register_offset: int = 0) -> None:
        self.controller = controller
        self.offset = register_offset
        self.executing = False
        self.running = True
        self.pending: Callable[[], bool] | None = None
        self.outputs = {0: p.READY_FOR_COMMAND, 1: 0, 2: -2}
        self.unsupported: list[int] = []

    def _int(self, inputs: dict[str, Any], index: int) -> int:
        return int(inputs.get(f"input_int_register_{index + self.offset}", 0))

    def _double(self, inputs: dict[str, Any], index: int) -> float:
        return float(inputs.get(f"input_double_register_{index + self.offset}", 0.0))

    def _doubles(self, inputs: dict[str, Any], start: int, count: int = 6) -> np.ndarray:
        return np.array([self._double(inputs, start + i) for i in range(count)])

    def cycle(self, inputs: dict[str, Any]) -> None:
        """One pass of the main loop with this cycle's inputs."""
        if not self.running:
            return
        if self.pending is not None:  # a blocking command in progress
            if self.pending():
                self.pending = None
                self.outputs[0] = p.DONE_WITH_COMMAND
            return
        cmd = self._int(inputs, 0)
        if cmd in p.REALTIME_COMMANDS:
            self.running = self.process(cmd, inputs)
            self.outputs[0] = p.READY_FOR_COMMAND
        elif cmd == p.NO_CMD:
            self.executing = False
            self.outputs[0] = p.READY_FOR_COMMAND
        else:
            if not self.executing:
                self.running = self.process(cmd, inputs)
                if self.running and self.pending is None:
                    self.outputs[0] = p.DONE_WITH_COMMAND
            self.executing = True

    def process(self, cmd: int, inputs: dict[str, Any]) -> bool:
        """``process_cmd``: act on one command; ``False`` ends the program (``stopScript``)."""
        arm = self.controller.arm
        if cmd == p.SPEEDJ:
            arm.speedj(self._doubles(inputs, 0), self._double(inputs, 6))
            self.controller.on_speed_command()
        elif cmd in _STOP_TYPES:
            arm.stopj(self._double(inputs, 0))
            self.pending = arm.at_rest
        elif cmd == p.MOVEJ:
            arm.movej(self._doubles(inputs, 0), self._double(inputs, 6))
            if self._int(inputs, 1) != 1:  # synchronous: done once there
                self.pending = arm.at_rest
        elif cmd == p.SET_WATCHDOG:
            self.controller.set_watchdog(self._double(inputs, 0), f"input_int_register_{self.offset}")
        elif cmd == p.PROTECTIVE_STOP_CMD:
            self.controller.protective_stop()
        elif cmd == p.STOP_SCRIPT:
            return False
        elif cmd != p.WATCHDOG:  # the watchdog kick only refreshes the register
            self.unsupported.append(cmd)
        return True

    def register_values(self) -> dict[str, int]:
        """``output_int_register_0..2`` as the program last wrote them."""
        return {f"output_int_register_{i + self.offset}": v for i, v in self.outputs.items()}
