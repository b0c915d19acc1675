"""The emulator's TCP servers: RTDE (30004), dashboard (29999), and script (30002/30003).

Sources in ur_rtde 1.6.5: ``src/rtde.cpp`` (RTDE packets), ``src/dashboard_client.cpp`` (one
line per request and per answer, a welcome line on connect; ``PolyscopeVersion``, ``get serial
number``, ``stop``, ``unlock protective stop``, ``close safety popup``, ``is in remote control``; and,
as UR's dashboard server manual words them, ``robotmode`` (``Robotmode: RUNNING``), ``safetystatus``
(``Safetystatus: NORMAL``), ``programState`` (``STOPPED <program>``, ``PAUSED …``, ``PLAYING …``) and
``running`` (``Program running: true``), which the host asks to confirm the arm at rest)
and ``src/script_client.cpp`` (the whole program, ``def rtde_control(): ... end``, written to the
socket; nothing is read back).
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
from typing import Any

from snac_gym.real.emulator import protocol as p

log = logging.getLogger("snac_gym.emulate_ur")


def _recv_exact(sock: socket.socket, size: int) -> bytes:
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        if not chunk:
            raise ConnectionError("peer closed")
        data += chunk
    return data


class RTDEConnection:
    """One RTDE client: its recipes, its output rate, and its reader thread."""

    def __init__(self, controller: Any, sock: socket.socket) -> None:
        self.controller = controller
        self.sock = sock
        self.send_lock = threading.Lock()
        self.output: p.Recipe | None = None
        self.inputs: dict[int, p.Recipe] = {}
        self.frequency = 0.0
        self.started = False
        self.closed = False

    def send(self, data: bytes) -> None:
        if self.closed:
            return
        try:
            with self.send_lock:
                self.sock.sendall(data)
        except OSError:
            self.close()

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.controller.release_inputs(self)
            try:
                self.sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self.sock.close()

    def serve(self) -> None:
        """Read and answer packets until the client goes or the controller closes the link."""
        try:
            while not self.closed:
                size, kind = p.HEADER.unpack(_recv_exact(self.sock, p.HEADER.size))
                if size < p.HEADER.size:
                    raise p.ProtocolError(f"packet size {size} is shorter than its header")
                self.handle(kind, _recv_exact(self.sock, size - p.HEADER.size))
        except (OSError, ConnectionError):
            pass
        except p.ProtocolError as exc:
            log.warning("RTDE client error, closing: %s", exc)
            self.controller.protocol_errors.append(str(exc))
        finally:
            self.close()

    def handle(self, kind: int, body: bytes) -> None:
        if kind == p.RTDE_DATA_PACKAGE:
            self._data(body)
        elif kind == p.RTDE_REQUEST_PROTOCOL_VERSION:
            version = struct.unpack(">H", body)[0] if len(body) == 2 else -1
            self.send(p.packet(kind, bytes([version in (1, 2)])))
        elif kind == p.RTDE_GET_URCONTROL_VERSION:
            self.send(p.packet(kind, struct.pack(">IIII", *self.controller.version)))
        elif kind == p.RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS:
            self._setup_outputs(body)
        elif kind == p.RTDE_CONTROL_PACKAGE_SETUP_INPUTS:
            self._setup_inputs(body)
        elif kind in (p.RTDE_CONTROL_PACKAGE_START, p.RTDE_CONTROL_PACKAGE_PAUSE):
            ok = kind == p.RTDE_CONTROL_PACKAGE_PAUSE or self.output is not None
            self.started = ok and kind == p.RTDE_CONTROL_PACKAGE_START
            self.send(p.packet(kind, bytes([ok])))
        else:
            raise p.ProtocolError(f"unknown RTDE packet type {kind}")

    def _setup_outputs(self, body: bytes) -> None:
        if len(body) < 8:
            raise p.ProtocolError("output setup without a frequency")
        frequency = struct.unpack(">d", body[:8])[0]
        names = p.split_names(body[8:])
        types = [p.output_type(name) or "NOT_FOUND" for name in names]
        ok = names and "NOT_FOUND" not in types and 0 < frequency <= self.controller.frequency
        if ok:
            self.output, self.frequency = p.Recipe(1, names, types), frequency
        else:
            self.controller.protocol_errors.append(f"output setup refused: {names} at {frequency} Hz")
        self.send(p.packet(p.RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS, bytes([1 if ok else 0]) + ",".join(types).encode()))

    def _setup_inputs(self, body: bytes) -> None:
        names = p.split_names(body)
        types = [p.input_type(name) or "NOT_FOUND" for name in names]
        types = [
            ("IN_USE" if t != "NOT_FOUND" and self.controller.input_in_use(n, self) else t)
            for n, t in zip(names, types)
        ]
        recipe_id = 0
        if names and not {"NOT_FOUND", "IN_USE"} & set(types):
            recipe_id = len(self.inputs) + 1
            self.inputs[recipe_id] = p.Recipe(recipe_id, names, types)
            self.controller.claim_inputs(names, self)
        self.send(p.packet(p.RTDE_CONTROL_PACKAGE_SETUP_INPUTS, bytes([recipe_id]) + ",".join(types).encode()))

    def _data(self, body: bytes) -> None:
        if not body or body[0] not in self.inputs:
            raise p.ProtocolError(f"data package for unknown input recipe {body[0] if body else None}")
        self.controller.receive_inputs(body[0], self.inputs[body[0]].unpack(body[1:]))


def serve_dashboard(controller: Any, sock: socket.socket) -> None:
    """Answer dashboard requests line by line (port 29999)."""
    with sock:
        try:
            sock.sendall(b"Connected: Universal Robots Dashboard Server\n")
            buffer = b""
            while True:
                chunk = sock.recv(4096)
                if not chunk:
                    return
                buffer += chunk
                while b"\n" in buffer:
                    line, buffer = buffer.split(b"\n", 1)
                    request = line.decode(errors="replace").strip()
                    answer = controller.dashboard(request)
                    sock.sendall((answer + "\n").encode())
                    if request == "quit":
                        return
        except OSError:
            return


def serve_script(controller: Any, sock: socket.socket) -> None:
    """Collect programs sent to the script port and run them (ports 30002 and 30003)."""
    with sock:
        buffer = ""
        try:
            while True:
                chunk = sock.recv(65536)
                if not chunk:
                    return
                buffer += chunk.decode(errors="replace")
                buffer = _run_complete_programs(controller, buffer)
        except OSError:
            return


def _run_complete_programs(controller: Any, buffer: str) -> str:
    """Hand every complete top-level program of ``buffer`` (``def f():`` … ``end``) to the controller."""
    while True:
        lines = buffer.split("\n")
        if not lines or not lines[0].startswith("def "):
            head, sep, rest = buffer.partition("\n")
            if not sep:
                return buffer
            if head.strip():
                controller.secondary_command(head.strip())
            buffer = rest
            continue
        try:
            end = next(i for i, line in enumerate(lines) if i > 0 and line.rstrip() == "end")
        except StopIteration:
            return buffer
        controller.run_program("\n".join(lines[: end + 1]))
        buffer = "\n".join(lines[end + 1 :])
