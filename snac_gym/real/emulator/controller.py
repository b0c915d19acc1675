"""The emulated UR controller: state, control cycle, faults, and the servers ur_rtde talks to."""

from __future__ import annotations

import logging
import os
import re
import socket
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from typing_extensions import Self

from snac_gym.model.kinematics import Kinematics
from snac_gym.model.ur_models import SERIES_FREQUENCY, series_of, velocity_limits
from snac_gym.real.connections import DASHBOARD_PORT, PROTECTIVE_STOP_LOCKOUT
from snac_gym.real.emulator import protocol as p
from snac_gym.real.emulator.arm import EmulatedArm
from snac_gym.real.emulator.script import ControlScript
from snac_gym.real.emulator.servers import RTDEConnection, serve_dashboard, serve_script
from snac_gym.sampling import nominal_configuration

log = logging.getLogger("snac_gym.emulate_ur")

#: Standard ports of a UR controller, as offsets from the dashboard port (29999).
PORT_OFFSETS = {"dashboard": 0, "secondary": 3, "realtime": 4, "rtde": 5}
STANDARD_PORT_BASE = DASHBOARD_PORT
#: Controller versions reported (``getControllerVersion``): CB3 runs 3.x, e-Series 5.x.
VERSIONS = {"cb": (3, 15, 8, 106339), "e": (5, 11, 6, 108805)}
#: The events that record a controller stop (``status()["safety_stop_at"]``).
_SAFETY_STOPS = ("protective stop", "emergency stop")
#: Deceleration of the controller's own stops (program stopped, watchdog), rad/s².
STOP_DECELERATION = 10.0
#: Commands that move the arm: none may arrive while the controller reports a stop.
MOTION_COMMANDS = frozenset({p.SPEEDJ, p.MOVEJ})
#: The dashboard's answer to ``unlock protective stop`` within the lockout (PolyScope's wording).
UNLOCK_TOO_EARLY = (
    f"Cannot unlock protective stop until {PROTECTIVE_STOP_LOCKOUT:g}s after occurrence. "
    "Always inspect cause of protective stop before unlocking"
)


@dataclass
class ReceivedCommand:
    """A data package from the control client that carried a command register."""

    t: float
    command: int
    values: dict[str, Any]


class UREmulator:
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
            raise ValueError(f"the emulator listens on loopback addresses only (127.x.x.x), got {host!r}")
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

    # ----------------------------------------------------------------- life cycle
    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> UREmulator:
        """Bind the servers (waiting for busy standard ports) and start the control cycle.

        Raises:
            OSError: If the ports stay busy for ``bind_timeout`` s.
        """
        deadline = time.monotonic() + self.bind_timeout
        while True:
            try:
                self._bind_all()
                break
            except OSError as exc:
                if time.monotonic() >= deadline:
                    raise OSError(
                        f"cannot listen on {self.host} port {exc.filename}: {exc.strerror} "
                        "(another emulator or UR software running?)"
                    ) from exc
                time.sleep(0.2)
        for name, listener in zip(PORT_OFFSETS, self._listeners):
            self._spawn(self._accept_loop, listener, name)
        self._spawn(self._control_loop)
        self.event(f"listening on {self.host}: " + ", ".join(f"{k} {v}" for k, v in self.ports.items()))
        return self

    def _bind_all(self) -> None:
        listeners = []
        try:
            for name, offset in PORT_OFFSETS.items():
                port = self.ports.get(name, 0 if self.port_base == 0 else self.port_base + offset)
                sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                listeners.append(sock)
                try:
                    sock.bind((self.host, port))
                except OSError as exc:
                    exc.filename = str(port)
                    raise
                sock.listen(8)
                sock.settimeout(0.1)
                self.ports[name] = sock.getsockname()[1]
        except OSError:
            for sock in listeners:
                sock.close()
            raise
        self._listeners = listeners

    def _spawn(self, target: Any, *args: Any) -> None:
        thread = threading.Thread(
            target=self._at_priority, args=(target, *args), daemon=True, name=f"emulate-ur-{target.__name__}"
        )
        thread.start()
        self._threads.append(thread)

    def _at_priority(self, target: Any, *args: Any) -> None:
        """Run ``target`` under ``SCHED_FIFO`` at ``rt_priority`` (when set), every thread alike.

        The servers' threads need the interpreter lock that the control cycle needs: at normal
        priority on a busy host, one descheduled while holding it stalled the cycle (at 500 Hz,
        no package for 6 ms and more; a command read after the 10 ms watchdog had expired).
        """
        if self.rt_priority and target != self._control_loop:  # the cycle says so itself if not permitted
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.rt_priority))
            except (PermissionError, OSError, AttributeError):
                pass
        try:
            target(*args)
        except BaseException as exc:  # a dead thread would leave a controller that looks alive: stop it all
            self.failure = exc
            log.exception(
                "emulate-ur: %s ended by %s: %s; the emulator stops", target.__name__, type(exc).__name__, exc
            )
            self._stop.set()

    def close(self) -> None:
        """Stop the control cycle, close every connection and listener, and join the threads."""
        self._stop.set()
        with self.lock:
            for conn in list(self._connections):
                conn.close()
            for sock in self._sockets:
                _close_quietly(sock)
        for sock in self._listeners:
            _close_quietly(sock)
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout=2.0)
        self._threads = [t for t in self._threads if t.is_alive()]

    def _accept_loop(self, listener: socket.socket, name: str) -> None:
        while not self._stop.is_set():
            try:
                sock, _ = listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            sock.settimeout(None)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._serve(sock, name)

    def _serve(self, sock: socket.socket, name: str) -> None:
        with self.lock:
            if name == "rtde":
                conn = RTDEConnection(self, sock)
                self._connections.append(conn)
                self._spawn(conn.serve)
                return
            self._sockets.append(sock)
        if name == "dashboard":
            self._spawn(serve_dashboard, self, sock)
        else:
            self._spawn(serve_script, self, sock)

    def event(self, text: str, level: int = logging.INFO) -> None:
        """Record (and log, at ``level``: a fault of the host at WARNING) something the controller did."""
        self.events.append((time.monotonic(), text))
        log.log(level, text)

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
            due = [c for c in self._connections if c.started and c.output is not None and self._due(c)]
            if due:
                self._awaiting_fresh_state = False
                if self._stopped_since is None and self.safety_bits != 1 << p.SAFETY_NORMAL:
                    self._stopped_since = now
        for conn in due:
            conn.send(conn.output.pack(values))  # type: ignore[union-attr]

    def _due(self, conn: RTDEConnection) -> bool:
        every = max(1, round(self.frequency / conn.frequency))
        return self._cycle % every == 0

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

    def _end_program(self, reason: str, level: int = logging.INFO) -> None:
        self.runtime_state = p.RUNTIME_STOPPED
        self.arm.stopj(STOP_DECELERATION)
        self._watchdog = None
        self.event(reason, level)

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

    # ----------------------------------------------------------------- dashboard
    def dashboard(self, request: str) -> str:
        """The dashboard server's answer to one request line."""
        major, minor, bugfix, build = self.version
        with self.lock:
            answers = {
                "PolyscopeVersion": f"URSoftware {major}.{minor}.{bugfix}.{build} (emulated)",
                "get serial number": "20235500001",
                "get robot model": self.arm.robot.upper(),
                "is in remote control": "true",
                "robotmode": "Robotmode: RUNNING",
                "safetystatus": f"Safetystatus: {self._safety_name()}",
                "safetymode": f"Safetymode: {self._safety_name()}",
                "running": f"Program running: {str(self.runtime_state == p.RUNTIME_PLAYING).lower()}",
                "programState": f"{self._program_state()} {self.programs[-1] if self.programs else '<unnamed>'}",
                "close safety popup": "closing safety popup",
                "quit": "Disconnected",
            }
            if request in answers:
                return answers[request]
            if request == "stop":
                if self.runtime_state != p.RUNTIME_STOPPED:
                    self._end_program("program stopped from the dashboard")
                return "Stopped"
            if request == "unlock protective stop":
                return self._unlock_protective_stop()
        return f"could not understand: '{request}'"

    def _program_state(self) -> str:
        """The dashboard's ``programState`` word: ``PLAYING``, ``PAUSED`` or ``STOPPED`` (the RTDE runtime state)."""
        return {p.RUNTIME_PLAYING: "PLAYING", p.RUNTIME_PAUSED: "PAUSED"}.get(self.runtime_state, "STOPPED")

    def _safety_name(self) -> str:
        if self.safety_bits & (1 << p.SAFETY_EMERGENCY_STOPPED):
            return "SYSTEM_EMERGENCY_STOP"
        if self.safety_bits & (1 << p.SAFETY_PROTECTIVE_STOPPED):
            return "PROTECTIVE_STOP"
        return "NORMAL"

    def _unlock_protective_stop(self) -> str:
        """PolyScope's rule: a protective stop can be unlocked only 5 s after it occurred."""
        if self._safety_name() != "PROTECTIVE_STOP":
            return "Cannot unlock protective stop"
        if time.monotonic() - self._protective_stop_at < PROTECTIVE_STOP_LOCKOUT:
            self.event("protective stop unlock refused: within the 5 s lockout")
            return UNLOCK_TOO_EARLY
        self._release_safety()
        self.event("protective stop unlocked from the dashboard")
        return "Protective stop releasing"

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
                _close_quietly(listener)
            for conn in list(self._connections):
                conn.close()
            for sock in self._sockets:
                _close_quietly(sock)
            self._sockets.clear()
            self.event("connections dropped")

    def _restore_link(self) -> None:
        try:
            self._bind_all()
        except OSError as exc:  # taken meanwhile: retried next cycle
            self.event(f"link not restored yet: {exc}")
            return
        self._link_down = False
        self._awaiting_fresh_state = True
        for name, listener in zip(PORT_OFFSETS, self._listeners):
            self._spawn(self._accept_loop, listener, name)
        self.event("link restored")

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


def _check_duration(name: str, seconds: float, allow_inf: bool = False) -> None:
    ok = isinstance(seconds, (int, float)) and seconds >= 0 and (allow_inf or np.isfinite(seconds))
    if not ok or np.isnan(seconds):
        raise ValueError(f"{name} must be a non-negative number of seconds, got {seconds!r}")


#: The argument checks of the faults that take arguments: run by each fault, and before, when it is scheduled.
_FAULT_ARGUMENTS: dict[str, Any] = {
    "latency_spike": lambda seconds: _check_duration("latency spike", seconds),
    "drop_connection": lambda refuse_for=float("inf"): _check_duration("refuse_for", refuse_for, allow_inf=True),
}


def _close_quietly(sock: socket.socket) -> None:
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    sock.close()
