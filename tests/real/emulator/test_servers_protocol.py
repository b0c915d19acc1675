"""The emulated controller's RTDE and dashboard servers, spoken to byte by byte (no ur_rtde).

The emulator runs in this process on free ports (``port_base=0``), so these tests can run beside
``tests/realtime/test_emulator.py`` and each other.
"""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Iterator

import numpy as np
import pytest

from snac_gym.real.connections import PROTECTIVE_STOP_LOCKOUT
from snac_gym.real.emulator import UREmulator
from snac_gym.real.emulator import protocol as p
from snac_gym.real.emulator.controller import UNLOCK_TOO_EARLY


@pytest.fixture
def emulator() -> Iterator[UREmulator]:
    with UREmulator(port_base=0) as emu:
        yield emu


def _connect(emu: UREmulator, name: str = "rtde") -> socket.socket:
    return socket.create_connection((emu.host, emu.ports[name]), timeout=2.0)


def _request(sock: socket.socket, kind: int, payload: bytes = b"") -> tuple[int, bytes]:
    sock.sendall(p.packet(kind, payload))
    return _read(sock)


def _read(sock: socket.socket) -> tuple[int, bytes]:
    size, kind = p.HEADER.unpack(sock.recv(3, socket.MSG_WAITALL))
    body = sock.recv(size - 3, socket.MSG_WAITALL) if size > 3 else b""
    return kind, body


def test_version_negotiation_and_controller_version(emulator):
    with _connect(emulator) as sock:
        assert _request(sock, p.RTDE_REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2)) == (86, b"\x01")
        assert _request(sock, p.RTDE_REQUEST_PROTOCOL_VERSION, struct.pack(">H", 7)) == (86, b"\x00")
        kind, body = _request(sock, p.RTDE_GET_URCONTROL_VERSION)
        assert kind == 118 and struct.unpack(">IIII", body)[:2] == (3, 15)


def test_output_recipe_streams_at_the_asked_rate_and_unknown_names_are_refused(emulator):
    with _connect(emulator) as sock:
        names = b"timestamp,actual_q,safety_status_bits,"
        kind, body = _request(sock, p.RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS, struct.pack(">d", 125.0) + names)
        assert kind == 79 and body == b"\x01DOUBLE,VECTOR6D,UINT32"
        assert _request(sock, p.RTDE_CONTROL_PACKAGE_START) == (83, b"\x01")
        recipe = p.Recipe(1, ["timestamp", "actual_q", "safety_status_bits"], ["DOUBLE", "VECTOR6D", "UINT32"])
        stamps = []
        for _ in range(3):
            kind, body = _read(sock)
            assert kind == 85 and body[0] == 1
            values = recipe.unpack(body[1:])
            stamps.append(values["timestamp"])
        assert np.allclose(np.diff(stamps), 0.008)
        np.testing.assert_allclose(values["actual_q"], emulator.arm.q)
        assert values["safety_status_bits"] == 1
    with _connect(emulator) as sock:
        kind, body = _request(
            sock, p.RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS, struct.pack(">d", 125.0) + b"actual_q,warp_drive"
        )
        assert body == b"\x00VECTOR6D,NOT_FOUND"
        assert _request(sock, p.RTDE_CONTROL_PACKAGE_START) == (83, b"\x00")  # nothing set up: refused


def test_input_registers_held_by_one_client_are_in_use_for_another(emulator):
    with _connect(emulator) as first, _connect(emulator) as second:
        assert _request(first, p.RTDE_CONTROL_PACKAGE_SETUP_INPUTS, b"input_int_register_0,") == (73, b"\x01INT32")
        assert _request(second, p.RTDE_CONTROL_PACKAGE_SETUP_INPUTS, b"input_int_register_0,") == (73, b"\x00IN_USE")
        first.sendall(p.packet(p.RTDE_DATA_PACKAGE, b"\x01" + struct.pack(">i", 42)))
        deadline = time.monotonic() + 2.0
        while emulator.inputs.get("input_int_register_0") != 42 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert emulator.inputs["input_int_register_0"] == 42


def test_a_malformed_package_closes_the_link_with_a_recorded_reason(emulator):
    with _connect(emulator) as sock:
        sock.sendall(p.packet(p.RTDE_DATA_PACKAGE, b"\x07abc"))  # no such input recipe
        assert sock.recv(10) == b""
    assert emulator.protocol_errors == ["data package for unknown input recipe 7"]


def test_dashboard_answers_the_requests_ur_rtde_makes(emulator):
    with _connect(emulator, "dashboard") as sock:
        reader = sock.makefile("r")
        assert reader.readline().startswith("Connected: Universal Robots Dashboard Server")
        for request, answer in [
            ("PolyscopeVersion", "URSoftware 3.15.8.106339 (emulated)"),
            ("is in remote control", "true"),
            ("unlock protective stop", "Cannot unlock protective stop"),
            ("warp 9", "could not understand: 'warp 9'"),
        ]:
            sock.sendall((request + "\n").encode())
            assert reader.readline().strip() == answer
        emulator.protective_stop()
        sock.sendall(b"unlock protective stop\n")  # within UR's 5 s lockout: refused, still stopped
        assert reader.readline().strip() == UNLOCK_TOO_EARLY
        assert emulator.safety_bits == 1 << p.SAFETY_PROTECTIVE_STOPPED
        emulator._protective_stop_at -= PROTECTIVE_STOP_LOCKOUT  # as if 5 s had passed
        sock.sendall(b"unlock protective stop\n")
        assert reader.readline().strip() == "Protective stop releasing"
    assert emulator.safety_bits == 1
    assert emulator.runtime_state == p.RUNTIME_STOPPED  # the program does not resume by itself


def _speedj_package(recipe_id: int) -> bytes:
    return p.packet(p.RTDE_DATA_PACKAGE, bytes([recipe_id]) + struct.pack(">i", p.SPEEDJ))


def _wait_for(condition, timeout: float = 2.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.005)


def test_motion_commands_during_a_stop_or_before_a_fresh_state_are_recorded(emulator):
    with _connect(emulator) as sock:
        _request(sock, p.RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS, struct.pack(">d", 125.0) + b"timestamp,")
        assert _request(sock, p.RTDE_CONTROL_PACKAGE_SETUP_INPUTS, b"input_int_register_0,") == (73, b"\x01INT32")
        assert _request(sock, p.RTDE_CONTROL_PACKAGE_START) == (83, b"\x01")
        sock.sendall(_speedj_package(1))  # normal: nothing to record
        _wait_for(lambda: len(emulator.commands) == 1)
        assert emulator.unsafe_commands == []
        emulator.protective_stop()
        _wait_for(lambda: emulator._stopped_since is not None)  # a state package reported the stop
        time.sleep(0.05)
        sock.sendall(_speedj_package(1))
        _wait_for(lambda: emulator.unsafe_commands)
    ((_, text),) = emulator.unsafe_commands
    assert text.startswith("speedJ during PROTECTIVE_STOP (") and "ms after it was reported" in text
    delay_ms = float(text.split("(")[1].split(" ms")[0])
    assert delay_ms >= 50.0
    emulator.clear_faults()
    emulator.unsafe_commands.clear()
    emulator.drop_connection(refuse_for=0.0)
    _wait_for(lambda: not emulator._link_down)
    with _connect(emulator) as sock:  # back, and no state package sent yet: a command is unsafe
        assert _request(sock, p.RTDE_CONTROL_PACKAGE_SETUP_INPUTS, b"input_int_register_0,") == (73, b"\x01INT32")
        sock.sendall(_speedj_package(1))
        _wait_for(lambda: emulator.unsafe_commands)
    assert [text for _, text in emulator.unsafe_commands] == [
        "speedJ after the link came back, before any state package"
    ]


def test_a_program_that_is_not_ur_rtdes_script_is_not_run(emulator):
    with _connect(emulator, "realtime") as sock:
        sock.sendall(b"def my_prog():\n  movej([0,0,0,0,0,0])\nend\n")
    deadline = time.monotonic() + 2.0
    while not emulator.programs and time.monotonic() < deadline:
        time.sleep(0.01)
    assert emulator.programs == ["my_prog"] and not emulator.script
    assert any("not ur_rtde's control script" in text for _, text in emulator.events)


def test_the_emulator_refuses_bad_arguments():
    with pytest.raises(ValueError, match=r"host must be a loopback address \(127.x.x.x\), where"):
        UREmulator(host="0.0.0.0")
    with pytest.raises(ValueError, match="series must be one of"):
        UREmulator(series="x")
    with pytest.raises(ValueError, match="speed scaling must be in"):
        UREmulator(speed_scaling=0.0)
    with pytest.raises(ValueError, match="rt_priority"):
        UREmulator(rt_priority=120)
    emulator = UREmulator(port_base=0)
    with pytest.raises(ValueError, match="unknown fault"):
        emulator.schedule(1.0, "melt")
    with pytest.raises(ValueError, match="no RTDE watchdog is armed"):
        emulator.expire_watchdog()
