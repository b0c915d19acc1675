"""The RTDE wire format as ur_rtde 1.6.5 speaks it: packet types, variable types, recipes.

Sources (ur_rtde, https://gitlab.com/sdurobotics/ur_rtde, read from its public mirrors):

* ``include/ur_rtde/rtde.h``: the packet types (``RTDECommand``), the command ids
  (``RobotCommand::Type``: ``SPEEDJ = 9``, ``SPEED_STOP = 15``, ``SET_WATCHDOG = 35``,
  ``WATCHDOG = 99``, ``STOP_SCRIPT = 255`` ...).
* ``src/rtde.cpp``: a packet is ``uint16 size`` (header included, big-endian), ``uint8 type``,
  payload; ``sendOutputSetup`` sends a big-endian double (the frequency) then the names joined and
  ended by commas; ``sendInputSetup`` the names the same way; ``send`` a data package: the
  recipe id, then ``input_int_register_0`` (the command) and the doubles of the recipe.
* ``src/rtde_control_interface.cpp``: ``setupRecipes`` (the output recipe
  ``robot_status_bits, safety_status_bits, runtime_state, output_int_register_0..2,
  output_double_register_0..5`` and the numbered input recipes), ``sendCommand`` (the register
  handshake below), ``isProgramRunning`` (``runtime_state == PLAYING``), ``isProtectiveStopped``
  (bit 2 of ``safety_status_bits``).
* ``scripts/rtde_control.script``: the control script's main loop, which
  :mod:`snac_gym.real.emulator.script` re-enacts.

Types and names of the RTDE variables follow Universal Robots' RTDE guide
(https://www.universal-robots.com/articles/ur/interface-communication/real-time-data-exchange-rtde-guide/).
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass

from snac_gym.common.errors import ProtocolError

RTDE_REQUEST_PROTOCOL_VERSION = 86  # 'V'
RTDE_GET_URCONTROL_VERSION = 118  # 'v'
RTDE_TEXT_MESSAGE = 77  # 'M'
RTDE_DATA_PACKAGE = 85  # 'U'
RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS = 79  # 'O'
RTDE_CONTROL_PACKAGE_SETUP_INPUTS = 73  # 'I'
RTDE_CONTROL_PACKAGE_START = 83  # 'S'
RTDE_CONTROL_PACKAGE_PAUSE = 80  # 'P'
HEADER = struct.Struct(">HB")

#: Command ids of ur_rtde's control script (``RTDE::RobotCommand::Type``).
NO_CMD, MOVEJ, SPEEDJ, SPEED_STOP, PROTECTIVE_STOP_CMD = 0, 1, 9, 15, 31
STOPJ, SET_WATCHDOG, WATCHDOG, STOP_SCRIPT = 34, 35, 99, 255
#: Commands the script's main loop runs every cycle without the done/clear handshake.
REALTIME_COMMANDS = frozenset({24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})
#: ``output_int_register_0`` values of the script (``UR_CONTROLLER_RDY_FOR_CMD`` / ``_DONE_WITH_CMD``).
READY_FOR_COMMAND, DONE_WITH_COMMAND = 1, 2

#: ``runtime_state`` values.
RUNTIME_STOPPED, RUNTIME_PLAYING, RUNTIME_PAUSED = 1, 2, 4
#: Bits of ``safety_status_bits``.
SAFETY_NORMAL, SAFETY_PROTECTIVE_STOPPED, SAFETY_SYSTEM_EMERGENCY_STOPPED = 0, 2, 5
SAFETY_EMERGENCY_STOPPED = 7
#: ``safety_mode`` values.
SAFETY_MODE_NORMAL, SAFETY_MODE_PROTECTIVE_STOP, SAFETY_MODE_SYSTEM_EMERGENCY_STOP = 1, 3, 7
#: Bits of ``robot_status_bits``: power on, program running.
STATUS_POWER_ON, STATUS_PROGRAM_RUNNING = 0, 1
ROBOT_MODE_RUNNING = 7

_FORMATS = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}
_V6 = "VECTOR6D"
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE",
    "target_q": _V6,
    "target_qd": _V6,
    "target_qdd": _V6,
    "target_current": _V6,
    "target_moment": _V6,
    "actual_q": _V6,
    "actual_qd": _V6,
    "actual_current": _V6,
    "actual_current_window": _V6,
    "joint_control_output": _V6,
    "actual_TCP_pose": _V6,
    "actual_TCP_speed": _V6,
    "actual_TCP_force": _V6,
    "target_TCP_pose": _V6,
    "target_TCP_speed": _V6,
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": _V6,
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": _V6,
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "payload_inertia": _V6,
    "script_control_line": "UINT32",
    "ft_raw_wrench": _V6,
    "joint_position_deviation_ratio": "DOUBLE",
    "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "INT32",
    "tool_output_mode": "UINT8",
    "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8",
    "actual_current_as_torque": _V6,
}
INPUT_TYPES: dict[str, str] = {
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": _V6,
}
_REGISTER = re.compile(r"^(input|output)_(int|double|bit)_register_(\d+)$")
_REGISTER_TYPES = {"int": "INT32", "double": "DOUBLE", "bit": "BOOL"}


def register_type(name: str, direction: str) -> str | None:
    """Type of ``input_*_register_N`` / ``output_*_register_N`` (N in 0..47, bits 64..127), or ``None``."""
    match = _REGISTER.match(name)
    if match is None or match.group(1) != direction:
        return None
    index, kind = int(match.group(3)), match.group(2)
    valid = 64 <= index <= 127 if kind == "bit" else 0 <= index <= 47
    return _REGISTER_TYPES[kind] if valid else None


def output_type(name: str) -> str | None:
    """RTDE type of an output variable, ``None`` if the controller has no such output."""
    return OUTPUT_TYPES.get(name) or register_type(name, "output") or register_type(name, "input")


def input_type(name: str) -> str | None:
    """RTDE type of an input variable, ``None`` if the controller has no such input."""
    return INPUT_TYPES.get(name) or register_type(name, "input")


def packet(kind: int, payload: bytes = b"") -> bytes:
    """One RTDE packet: ``uint16`` size (header included), ``uint8`` type, payload."""
    return HEADER.pack(HEADER.size + len(payload), kind) + payload


def split_names(payload: bytes) -> list[str]:
    """Variable names of a setup request; ur_rtde ends each with a comma."""
    try:
        text = payload.decode("ascii")
    except UnicodeDecodeError as exc:
        raise ProtocolError("variable names are not ASCII") from exc
    return [name.strip() for name in text.split(",") if name.strip()]


@dataclass
class Recipe:
    """A set-up recipe: id, variable names, their RTDE types and the struct that packs them."""

    recipe_id: int
    names: list[str]
    types: list[str]

    def __post_init__(self) -> None:
        self.struct = struct.Struct(">" + "".join(_FORMATS[t] for t in self.types))

    def pack(self, values: dict[str, object]) -> bytes:
        """A data package of this recipe from ``values`` (name → scalar or sequence)."""
        flat: list[object] = []
        for name, kind in zip(self.names, self.types):
            value = values[name]
            if kind.startswith("VECTOR"):
                flat.extend(value)  # type: ignore[arg-type]
            else:
                flat.append(value)
        return packet(RTDE_DATA_PACKAGE, bytes([self.recipe_id]) + self.struct.pack(*flat))

    def unpack(self, body: bytes) -> dict[str, object]:
        """Values by name from a data package's body (without the recipe id).

        Raises:
            ProtocolError: If the body is not this recipe's size.
        """
        if len(body) != self.struct.size:
            raise ProtocolError(f"recipe {self.recipe_id} needs {self.struct.size} bytes, got {len(body)}")
        flat = list(self.struct.unpack(body))
        values: dict[str, object] = {}
        for name, kind in zip(self.names, self.types):
            count = int(kind[6]) if kind.startswith("VECTOR") else 1
            values[name] = tuple(flat[:count]) if count > 1 else flat[0]
            del flat[:count]
        return values
