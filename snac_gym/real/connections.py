"""Connections to the arm for the real-robot env: a small protocol, the ur_rtde connection, a wall-clock
simulated arm for rehearsal, and a dry-run wrapper that reads state but sends nothing.

A connection owns the link to the arm and the timing of one control period: the env calls
``start_period`` and ``command`` when it sends u, then ``end_period`` (which blocks until the
period is over), then ``read_state`` and ``state_timestamp``. ``stop`` must be safe to call at any
time, any number of times, and returns once the arm is at rest (or cannot be reached).
"""

from __future__ import annotations

import collections
import os
import pickle
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from snac_gym.common.errors import ConnectionFailure
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.ur_models import SERIES_FREQUENCY  # the controller generations' rates, re-exported here
from snac_gym.physics.bullet import PyBulletSim, SimulatedArm
from snac_gym.real.rtde_client import HEADER, RECONNECT_MARKERS, as_arrays, write_frame
from snac_gym.sampling import nominal_configuration

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


def probe_port(host: str, port: int, timeout: float) -> None:
    """Fail fast with one clear line when ``host:port`` does not accept TCP connections.

    ur_rtde's own connect blocks for the OS's TCP timeout on an unreachable host and prints to
    the terminal; a plain socket with a timeout answers within ``timeout`` seconds.

    Raises:
        ConnectionFailure: Refused, unreachable, unknown host or timed out.
    """
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return
    except socket.timeout as exc:
        raise ConnectionFailure(
            f"no answer from {host}:{port} within {timeout:g} s (is the arm on and the IP right?)"
        ) from exc
    except ConnectionRefusedError as exc:
        raise ConnectionFailure(
            f"connection to {host}:{port} refused (is the UR controller running at {host}?)"
        ) from exc
    except OSError as exc:
        raise ConnectionFailure(f"cannot reach {host}:{port}: {exc.strerror or exc}") from exc


#: The dashboard server's port on a UR controller (PolyScope's, fixed).
DASHBOARD_PORT = 29999
#: Robot modes (the dashboard's ``robotmode``) in which an arm whose program is stopped is held at rest by the
#: controller (position held, or brakes on). Not BACKDRIVE (the arm moves by hand), BOOTING, CONFIRM_SAFETY,
#: NO_CONTROLLER, DISCONNECTED or UPDATING_FIRMWARE: there the answer says nothing of rest.
HELD_ROBOT_MODES = frozenset({"RUNNING", "IDLE", "POWER_ON", "POWER_OFF"})
#: What the dashboard is asked to confirm rest (UR dashboard server: ``programState`` answers ``STOPPED <program>``,
#: ``PAUSED <program>`` or ``PLAYING <program>``; ``robotmode`` ``Robotmode: RUNNING``; ``safetystatus``
#: ``Safetystatus: NORMAL`` (software 3.11 and 5.4 onwards; older ones do not understand it, which is kept as said).
DASHBOARD_REST_REQUESTS = ("programState", "robotmode", "safetystatus")


def ask_dashboard(host: str, requests: Sequence[str], timeout: float, port: int = DASHBOARD_PORT) -> dict[str, str]:
    """One connection to the controller's dashboard server: each request's one-line answer.

    A plain socket with ``timeout`` s per operation (not ur_rtde), so that it answers from the host's own
    process whether or not the ur_rtde client still serves.

    Raises:
        OSError: Refused, unreachable, timed out, or closed before every answer came.
    """
    answers: dict[str, str] = {}
    with socket.create_connection((host, port), timeout=timeout) as sock:
        reader = sock.makefile("rb")
        if not reader.readline():  # the welcome line
            raise ConnectionError("the dashboard server closed the connection")
        for request in requests:
            sock.sendall(request.encode() + b"\n")
            line = reader.readline()
            if not line:
                raise ConnectionError(f"the dashboard server closed the connection before answering {request!r}")
            answers[request] = line.decode(errors="replace").strip()
    return answers


def _dashboard_word(answer: str, prefix: str) -> str:
    """``Robotmode: RUNNING`` -> ``RUNNING``; an answer without ``prefix`` (not understood) as it came."""
    head, sep, rest = answer.partition(":")
    return rest.strip() if sep and head.strip().lower() == prefix else answer


def confirm_rest_by_dashboard(
    ask: Callable[[Sequence[str]], dict[str, str]],
    within: float,
    settle: float,
    poll: float = 0.05,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> tuple[bool, str]:
    """Whether the dashboard server confirms the arm at rest within ``within`` s, and what it said.

    Rest is confirmed by two answers ``settle`` s apart (the controller's own stop ramp from the
    arm's last known speed), each with the program not running (``programState`` ``STOPPED`` or
    ``PAUSED``: nothing drives the arm) and the robot in a mode that holds it
    (:data:`HELD_ROBOT_MODES`). ``ask(requests)`` returns the answers or raises ``OSError``
    (unreachable); it is asked every ``poll`` s until then.

    Returns:
        ``(True, "dashboard: programState STOPPED …, robotmode RUNNING, safetystatus NORMAL")`` or
        ``(False, the last thing that kept it from confirming)``.
    """
    start = clock()
    stopped_since: float | None = None
    problem = "not asked"
    while True:
        try:
            answers = ask(DASHBOARD_REST_REQUESTS)
        except OSError as exc:
            problem, stopped_since = f"dashboard unreachable ({type(exc).__name__}: {exc})", None
        else:
            program = answers.get("programState", "")
            mode = _dashboard_word(answers.get("robotmode", ""), "robotmode")
            safety = _dashboard_word(answers.get("safetystatus", ""), "safetystatus")
            said = f"programState {program}, robotmode {mode}, safetystatus {safety}"
            if program.split(" ", 1)[0] in ("STOPPED", "PAUSED") and mode in HELD_ROBOT_MODES:
                now = clock()
                stopped_since = now if stopped_since is None else stopped_since
                if now - stopped_since >= settle:
                    return True, f"dashboard: {said}"
                problem = f"dashboard: {said}, not yet {settle:.2f} s (the stop ramp) after it first said so"
            else:
                problem, stopped_since = f"dashboard: {said}: the program still runs or the arm is not held", None
        if clock() - start >= within:
            return False, problem
        sleep(poll)


class URRTDEConnection:
    """A real UR arm through ur_rtde, whose client runs in a child process: ``speedJ`` streamed at the control rate.

    Each period: ``command`` (``speedJ(u, acceleration, dt)`` in the client), a wait until the
    period's end, then ``read_state`` (one RTDE package: q, θ̇, TCP pose, speed scaling, timestamp
    and safety bits). The controller-side watchdog (``setWatchdog`` on the command register,
    armed at the first command of each stream) stops the control script, and so the arm, if no
    command arrives for ``watchdog_periods`` periods; the next stream re-uploads the script.

    Isolation (:mod:`snac_gym.real.rtde_client`): ur_rtde runs in a child process, and every
    request has a deadline the parent enforces with ``select``, outside any lock ur_rtde holds.
    A request that misses its deadline, a client that crashes or exits, a link the client
    reports down, and any line in which ur_rtde says it is reconnecting by itself make the
    parent kill the client: the link counts as lost (:class:`ConnectionFailure`, reason in
    :attr:`failure`), nothing more is sent, and the controller's watchdog stops the arm. Nothing
    reconnects mid-run; a new run starts a new client.

    Args:
        host: IP address of the UR controller.
        kinematics: Model of the arm (UR10 by default).
        frequency: Control rate, Hz: 125 for CB-series, 500 for e-Series (see ``series``).
        series: ``"cb"`` or ``"e"``; sets ``frequency`` when that is not given.
        acceleration: Joint acceleration bound passed to ``speedJ``, rad/s² (of the leading joint).
            Keep it above the safety layer's ``max_joint_acceleration``: the shaped command already
            bounds the acceleration, and a lower ramp here makes the arm trail every command
            change (:func:`~snac_gym.apps.real.make_connection` passes twice the layer's bound).
        control: Open the control interface (``False`` for a dry run: state only, nothing sent).
        connect_timeout: Seconds to wait for the controller before giving up.
        watchdog_periods: Missed periods after which the controller's watchdog stops the arm.
        move_speed: Joint speed of ``move_to`` (``moveJ``), rad/s.
        stop_deceleration: Joint deceleration of ``speedStop``, rad/s².
        rest_timeout: Longest wait (s) for the arm to come to rest after ``speedStop``.
        confirm_timeout: Longest wait (s) for the dashboard server to confirm the arm at rest when RTDE
            cannot (a frozen state, a client gone): see :meth:`stop`.
        call_timeout: Deadline (s) of a ``speedJ`` or a state read (default: the watchdog's
            ``watchdog_periods`` periods: a client blocked longer has already let the
            controller's watchdog stop the arm, so waiting more gains nothing).

    Raises:
        ConnectionFailure: If the controller cannot be reached (within ``connect_timeout``).
    """

    RTDE_PORT = 30004
    #: Seconds the client may take to start (a Python interpreter, numpy and ur_rtde's imports).
    STARTUP_ALLOWANCE = 10.0
    #: Seconds between two attempts of :meth:`reconnect`.
    RECONNECT_PAUSE = 0.5

    def __init__(
        self,
        host: str,
        kinematics: Kinematics | None = None,
        frequency: float | None = None,
        series: str = "cb",
        acceleration: float = 1.0,
        control: bool = True,
        connect_timeout: float = 3.0,
        watchdog_periods: int = 5,
        move_speed: float = 0.3,
        stop_deceleration: float = 2.0,
        rest_timeout: float = 3.0,
        call_timeout: float | None = None,
        confirm_timeout: float = 2.0,
    ) -> None:
        if series not in SERIES_FREQUENCY:
            raise ValueError(f"series must be one of {sorted(SERIES_FREQUENCY)}, got {series!r}")
        self.kinematics = kinematics if kinematics is not None else Kinematics("ur10")
        self.frequency = float(frequency) if frequency is not None else SERIES_FREQUENCY[series]
        self.dt = 1.0 / self.frequency
        self.acceleration = float(acceleration)
        self.move_speed = float(move_speed)
        self.stop_deceleration = float(stop_deceleration)
        self.rest_timeout = float(rest_timeout)
        self.confirm_timeout = float(confirm_timeout)
        self.watchdog_frequency = self.frequency / watchdog_periods
        self.watchdog_periods = int(watchdog_periods)
        #: The controller's watchdog period in force during a stream (s): no command for this long stops the program.
        self.watchdog_period = watchdog_periods / self.frequency
        self.call_timeout = float(call_timeout) if call_timeout is not None else watchdog_periods * self.dt
        self.host = host
        self.control = control
        self.connect_timeout = float(connect_timeout)
        #: One entry per link lost and reconnected (:meth:`reconnect`): the client's reason and last lines.
        self.lost_links: list[dict[str, Any]] = []
        self.stop_calls = 0
        self.last_stop: str | None = None
        #: How the last stop ended (:meth:`stop_record`'s fields), or ``None`` before the first stop that followed a
        #: command.
        self.rest: dict[str, Any] | None = None
        self._sent = False  # a command or move sent since the last stop's record
        self._watchdog_armed = False  # a stream armed the controller's watchdog (setWatchdog) since the last moveJ
        self._streaming = False
        self._snapshot: tuple[np.ndarray, np.ndarray, np.ndarray, float, float, str] | None = None
        self._fresh = False
        probe_port(host, self.RTDE_PORT, connect_timeout)
        self._client = ClientProcess()
        try:
            state = self._call(
                "connect", host, self.frequency, control, timeout=connect_timeout + self.STARTUP_ALLOWANCE
            )
        except ConnectionFailure as exc:
            self._client.close(0.0)
            raise ConnectionFailure(f"ur_rtde could not connect to {host}: {exc}") from None
        except BaseException:
            self._client.close(0.0)
            raise
        self._keep(state)

    @property
    def failure(self) -> str | None:
        """Why the client was given up (killed, crashed, link lost), or ``None`` while it serves."""
        return self._client.failure

    @property
    def client_pid(self) -> int:
        """Process id of the ur_rtde client."""
        return self._client.pid

    @property
    def client_output(self) -> list[str]:
        """The last lines ur_rtde printed (it prints to the process's streams, not through Python)."""
        return list(self._client.output)

    def _call(self, name: str, *args: object, timeout: float) -> Any:
        status, payload = self._client.call(name, args, timeout)
        if status == "ok":
            return payload
        if status == "lost":
            reason = f"connection to the arm at {self.host} {payload}"
        else:
            reason = f"ur_rtde {name} failed: {payload}"
        self._client.abandon(reason)
        raise ConnectionFailure(reason)

    def _keep(self, state: dict[str, Any]) -> None:
        self._snapshot = as_arrays(state)
        self._fresh = True

    def read_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint state of one RTDE package (with its TCP pose, speed scaling, timestamp and safety bits)."""
        self._keep(self._call("state", timeout=self.call_timeout))
        return self._snapshot[0].copy(), self._snapshot[1].copy()  # type: ignore[index]

    def reported_tcp_position(self) -> np.ndarray:
        """The controller's TCP position (``actual_TCP_pose[:3]``, m, UR base frame) of the last read.

        With no TCP offset set on the pendant it is the flange (``tool0``) in the ``base`` frame,
        the point and frame of :class:`~snac_gym.model.kinematics.Kinematics`' defaults.
        """
        return self._last_snapshot()[2][:3].copy()

    def speed_scaling(self) -> float:
        """The controller's speed scaling of the last read (the pendant's slider, 1.0 = 100 %)."""
        return self._last_snapshot()[3]

    def _last_snapshot(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float, str]:
        if self._snapshot is None:
            self.read_state()
        return self._snapshot  # type: ignore[return-value]

    def start_period(self) -> float:
        self._fresh = False
        return time.perf_counter()

    def command(self, velocities: np.ndarray) -> None:
        if not self.control:
            raise RuntimeError("this connection was opened without the control interface (dry run)")
        # The first command of a stream may re-upload the control script: it gets the longer deadline.
        timeout = self.call_timeout if self._streaming else self.rest_timeout + self.call_timeout
        self._sent = True
        self._watchdog_armed = True
        accepted = self._call(
            "command", list(map(float, velocities)), self.acceleration, self.watchdog_frequency, self.rest_timeout,
            timeout=timeout,
        )  # fmt: skip
        self._streaming = True
        if not accepted:
            raise ConnectionFailure(f"the arm at {self.host} rejected speedJ (connection lost or program stopped)")

    def end_period(self, period_start: float) -> None:
        wait_until(period_start + self.dt)

    def state_timestamp(self) -> float:
        return self._last_snapshot()[4]

    def stop(self) -> None:
        """``speedStop`` and wait for rest, in the client, within ``rest_timeout`` + 1 s; then, if RTDE could
        not show the arm at rest, ``stopScript`` and the dashboard server's word for it.

        Rest is read from RTDE only from a package newer than the stop (a frozen state cannot show
        it). Where RTDE cannot (its state frozen, the arm still moving after ``rest_timeout``, the
        client gone), the host ends the control script (``stopScript``, if the client still serves)
        and asks the dashboard server (port 29999, from this process, not through ur_rtde) within
        ``confirm_timeout`` s (:func:`confirm_rest_by_dashboard`). Either way :attr:`rest` says which
        source confirmed rest and when, or that none did and why (:meth:`stop_record`). With the
        client gone the controller's watchdog, armed for every stream, stops the arm: a stop never
        raises :class:`ConnectionFailure`. Once a stop has its record, a stop with nothing sent since
        keeps it and sends nothing.
        """
        self._fresh = False
        if not self.control:
            return
        self._streaming = False
        self.stop_calls += 1
        if not self._sent and self.rest is not None:  # nothing sent since that stop: its record holds
            return
        start = time.monotonic()
        speed = float(np.max(np.abs(self._snapshot[1]))) if self._snapshot is not None else float("nan")
        if self._client.failure is not None:
            self.last_stop = "client gone: left to the controller's watchdog"
        else:
            try:
                self.last_stop = self._call(
                    "stop", self.stop_deceleration, self.rest_timeout, timeout=self.rest_timeout + 1.0
                )
            except ConnectionFailure:
                self.last_stop = "client gone: left to the controller's watchdog"
        self._sent = False
        if self.last_stop == "at rest":
            self.rest = self._record(
                start, True, "rtde: joint speeds under 0.001 rad/s in a package newer than speedStop"
            )
            return
        script = None
        if self._client.failure is None:
            try:
                script = self._call("stop_script", timeout=self.rest_timeout + 1.0)
            except ConnectionFailure:
                script = None
        # The controller's own stop ramp from the last speed read (a non-finite one: the arm's fastest joint).
        if not np.isfinite(speed):
            speed = float(np.max(self.kinematics.velocity_limits))
        settle = speed / self.stop_deceleration
        confirmed, said = confirm_rest_by_dashboard(
            lambda requests: ask_dashboard(self.host, requests, timeout=min(0.5, self.confirm_timeout)),
            self.confirm_timeout, settle,
        )  # fmt: skip
        how = (
            said
            if confirmed
            else (f"nothing confirmed the arm at rest within {self.confirm_timeout:g} s: RTDE {self.last_stop}; {said}")
        )
        self.rest = self._record(start, confirmed, how, script=script, settle=settle)

    def _record(
        self, start: float, confirmed: bool, how: str, script: str | None = None, settle: float | None = None
    ) -> dict[str, Any]:
        client_gone = self._client.failure is not None and script is None
        watchdog = (
            f"the controller's watchdog: no command for {self.watchdog_period * 1e3:.0f} ms "
            f"({self.watchdog_periods} periods) stops the program and the arm"
        )
        if self.last_stop == "at rest":
            stopped_by = "speedStop (host)"
        elif script == "control script stopped":
            stopped_by = "speedStop, then stopScript (host)" + (
                f"; {watchdog}, which may have done it first" if self._watchdog_armed else ""
            )
        elif self._watchdog_armed:
            stopped_by = watchdog
        else:
            stopped_by = "unknown: no stream armed the controller's watchdog since the last moveJ"
        return {
            "rest_confirmed": confirmed,
            "rest_confirmed_by": how if confirmed else None,
            "rest_not_confirmed": None if confirmed else how,
            "rest_confirmed_after_s": round(time.monotonic() - start, 4) if confirmed else None,
            "stop_took_s": round(time.monotonic() - start, 4),
            "stopped_by": stopped_by,
            "client_gone": client_gone,
            "stop_script": script,
            "stop_ramp_s": None if settle is None else round(settle, 4),
            "watchdog_armed": self._watchdog_armed,
            "watchdog_period_s": self.watchdog_period,
        }

    def stop_record(self) -> dict[str, Any]:
        """How the last stop ended, for the run's record: ``rest_confirmed`` (``None``: no stop after a command),
        ``rest_confirmed_by`` (the source: ``rtde: …`` or ``dashboard: programState STOPPED …``),
        ``rest_confirmed_after_s`` (from the stop's start), ``rest_not_confirmed`` (why not), ``stopped_by``
        (``speedStop``, ``stopScript`` or the controller's watchdog) and ``watchdog_period_s``."""
        if self.rest is None:
            return {"rest_confirmed": None, "watchdog_period_s": self.watchdog_period}
        return dict(self.rest)

    def move_to(self, q: np.ndarray) -> None:
        if not self.control:
            raise RuntimeError("cannot move the arm in a dry run")
        q = np.asarray(q, dtype=float)
        self._fresh = False
        self._sent = True
        self._watchdog_armed = False  # the program may be new (re-uploaded): no stream has armed its watchdog
        current = self._last_snapshot()[0]
        travel = float(np.max(np.abs(q - current))) / self.move_speed if current.shape == q.shape else 60.0
        timeout = 2.0 * travel + 2.0 * self.rest_timeout + 2.0  # moveJ's ramps, and a script re-upload
        if not self._call("move_to", list(map(float, q)), self.move_speed, self.rest_timeout, timeout=timeout):
            raise ConnectionFailure(f"moveJ to the start pose failed on {self.host}")

    def safety_state(self) -> str:
        if not self._fresh:  # reset asks with no read in between: read now
            self.read_state()
        return self._last_snapshot()[5]

    def unlock_protective_stop(self) -> str | None:
        """The dashboard server's ``unlock protective stop`` (ur_rtde's ``DashboardClient``).

        Returns ``None`` once the controller releases the stop, else its answer (within
        :data:`PROTECTIVE_STOP_LOCKOUT` of the stop: refused). The dashboard is asked from the
        client process, under the same deadline as any request.
        """
        released, answer = self._call("unlock_protective_stop", self.host, timeout=self.rest_timeout + 1.0)
        return None if released else str(answer)

    def reconnect(self, within: float) -> int:
        """Start a new ur_rtde client and connect it, trying until ``within`` s have passed.

        The old client (given up after the link was lost) is closed first; its reason and last
        lines are kept in :attr:`lost_links`. Returns the number of attempts.

        Raises:
            ConnectionFailure: If no attempt connected within ``within`` s (the last reason given).
        """
        self.lost_links.append({"failure": self._client.failure, "client_output": list(self._client.output)})
        self._client.close(0.0)
        self._streaming = False
        self._fresh = False
        deadline = time.monotonic() + within
        attempts = 0
        while True:
            attempts += 1
            remaining = deadline - time.monotonic()
            try:
                probe_port(self.host, self.RTDE_PORT, max(min(self.connect_timeout, remaining), 0.05))
                client = ClientProcess()
                self._client = client
                self._keep(self._call("connect", self.host, self.frequency, self.control,
                                      timeout=self.connect_timeout + self.STARTUP_ALLOWANCE))  # fmt: skip
                return attempts
            except ConnectionFailure as exc:
                reason = str(exc)
                self._client.close(0.0)
            if time.monotonic() + self.RECONNECT_PAUSE >= deadline:
                raise ConnectionFailure(
                    f"the link to the arm at {self.host} did not come back within {within:g} s "
                    f"({attempts} attempts; last: {reason})"
                )
            time.sleep(self.RECONNECT_PAUSE)

    def close(self) -> None:
        self.stop()
        self._client.close(2.0)


class ClientProcess:
    """The ur_rtde client's process, seen from the parent: requests with deadlines, and its output.

    :meth:`abandon` (from any thread) records why and kills it; the first reason is kept.
    """

    def __init__(self) -> None:
        self.failure: str | None = None
        self.output: collections.deque[str] = collections.deque(maxlen=50)
        self._lock = threading.Lock()
        self._seq = 0
        self._buffer = b""
        self._process = subprocess.Popen(
            [sys.executable, "-c", "from snac_gym.real.rtde_client import serve; serve()"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            bufsize=0,
            start_new_session=True,  # a Ctrl-C at the terminal reaches the parent only, which stops the arm
        )
        self._reader = threading.Thread(target=self._watch_output, name="ur_rtde-output", daemon=True)
        self._reader.start()

    @property
    def pid(self) -> int:
        return self._process.pid

    def _watch_output(self) -> None:
        for raw in self._process.stderr:  # type: ignore[union-attr]
            line = raw.decode(errors="replace").rstrip()
            if not line:
                continue
            self.output.append(line)
            if any(marker in line.lower() for marker in RECONNECT_MARKERS):
                self.abandon(
                    f"link to the arm lost: ur_rtde began to reconnect by itself ({line.strip()!r}), client ended"
                )

    def abandon(self, reason: str) -> None:
        with self._lock:
            if self.failure is None:
                self.failure = reason
            if self._process.returncode is None:
                try:
                    self._process.kill()
                except OSError:
                    pass

    def call(self, name: str, args: tuple[object, ...], timeout: float) -> tuple[str, Any]:
        """Send one request and wait for its reply, at most ``timeout`` s.

        Raises:
            ConnectionFailure: With the reason, if the client is gone, crashes, or misses the deadline.
        """
        if self.failure is not None:
            raise ConnectionFailure(self.failure)
        self._seq += 1
        seq = self._seq
        try:
            write_frame(self._process.stdin.fileno(), (seq, name, args))  # type: ignore[union-attr]
        except (BrokenPipeError, ValueError, OSError):
            self._ended(name)
        deadline = time.perf_counter() + timeout
        while True:
            frame = self._next_frame(deadline, name, timeout)
            if frame[0] == seq:  # a reply to a request a signal interrupted is dropped
                return frame[1], frame[2]

    def _next_frame(self, deadline: float, name: str, timeout: float) -> tuple[int, str, Any]:
        fd = self._process.stdout.fileno()  # type: ignore[union-attr]
        while True:
            if len(self._buffer) >= HEADER.size:
                size = HEADER.unpack_from(self._buffer)[0] + HEADER.size
                if len(self._buffer) >= size:
                    frame, self._buffer = self._buffer[HEADER.size : size], self._buffer[size:]
                    return pickle.loads(frame)
            remaining = deadline - time.perf_counter()
            if remaining <= 0 or not select.select([fd], [], [], remaining)[0]:
                if self._process.poll() is not None:
                    self._ended(name)
                self.abandon(
                    f"ur_rtde did not return from {name} within {timeout * 1e3:.0f} ms (client killed; "
                    "the controller's watchdog stops the arm)"
                )
                raise ConnectionFailure(self.failure)
            data = os.read(fd, 65536)
            if not data:
                self._ended(name)
            self._buffer += data

    def _ended(self, name: str) -> None:
        """The client's pipe closed: it crashed or was killed. Raises :class:`ConnectionFailure`."""
        try:
            code = self._process.wait(timeout=1.0)
        except Exception:  # noqa: BLE001 - still not gone: kill it below
            code = None
        if code is not None and code < 0:
            how = f"was killed by {signal.Signals(-code).name}"
        else:
            how = f"exited with code {code}"
        last = f" after printing {self.output[-1]!r}" if self.output else ""
        self.abandon(f"the ur_rtde client {how} during {name}{last}")
        raise ConnectionFailure(self.failure)

    def close(self, timeout: float) -> None:
        """Ask the client to disconnect and leave; kill it if it does not within ``timeout`` s."""
        if self.failure is None and timeout > 0:
            try:
                self.call("close", (), timeout)
            except ConnectionFailure:
                pass
        process = self._process
        for stream in (process.stdin, process.stdout):
            try:
                stream.close()  # type: ignore[union-attr]
            except OSError:
                pass
        try:
            process.wait(timeout=max(timeout, 0.1))
        except Exception:  # noqa: BLE001 - it would not leave: kill it
            process.kill()
            process.wait()
        self._reader.join(timeout=1.0)


class SimulatedConnection:
    """The PyBullet UR arm behind the connection protocol, run in wall-clock time.

    ``end_period`` steps the physics by one period and then sleeps until the period's end, so a
    whole real-robot loop (policy, safety layer, timing, deadlines) is rehearsed without hardware.
    ``realtime=False`` skips the sleep (tests). ``inject_fault`` makes the next reads report a
    protective or emergency stop, as the controller would.

    Args:
        kinematics: Model of the arm (UR10 by default).
        frequency: Control rate, Hz.
        n_substeps: Physics steps per period.
        realtime: Sleep to hold the wall-clock period.
        home: Where the simulated arm is parked when the connection starts (default: the
            nominal elbow-up pose, the paper's θ0 for a 6-joint UR arm), as a real arm would be.
    """

    def __init__(
        self,
        kinematics: Kinematics | None = None,
        frequency: float = 125.0,
        n_substeps: int = 3,
        realtime: bool = True,
        home: np.ndarray | None = None,
    ) -> None:
        self.kinematics = kinematics if kinematics is not None else Kinematics("ur10")
        self.frequency = float(frequency)
        self.dt = 1.0 / self.frequency
        self.realtime = realtime
        self.sim = PyBulletSim(self.dt, n_substeps)
        self.arm = SimulatedArm(self.sim, self.kinematics, meshes=False)  # never drawn: loads in ms, not 0.3 s
        self._initial_state = self.sim.save_state()
        self.arm.set_joint_positions(
            nominal_configuration(self.kinematics) if home is None else np.asarray(home, float)
        )
        self._fault = NORMAL
        self._periods = 0
        self.commands_sent = 0
        self.stop_calls = 0
        self.stopped = False

    def read_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self.arm.joint_state()

    def start_period(self) -> float:
        return time.perf_counter()

    def command(self, velocities: np.ndarray) -> None:
        if self._fault != NORMAL:
            return  # a stopped controller ignores commands, as the real one does
        self.arm.command_velocities(np.asarray(velocities, dtype=float))
        self.commands_sent += 1
        self.stopped = False

    def end_period(self, period_start: float) -> None:
        self.sim.step()
        self._periods += 1
        if self.realtime:
            wait_until(period_start + self.dt)

    def state_timestamp(self) -> float:
        return self._periods * self.dt

    def stop(self) -> None:
        """Command zero velocity and run the physics until the arm is at rest, as ``speedStop`` does."""
        self.stop_calls += 1
        self.stopped = True
        if self.sim.client < 0:
            return
        self.arm.command_velocities(np.zeros(self.kinematics.n_joints))
        for _ in range(int(self.frequency)):  # at most 1 s of simulated deceleration
            if np.max(np.abs(self.arm.joint_state()[1])) < 1e-3:
                return
            self.end_period(time.perf_counter())

    def move_to(self, q: np.ndarray) -> None:
        self.sim.restore_state(self._initial_state)
        self.arm.set_joint_positions(np.asarray(q, dtype=float))
        self._fault = NORMAL
        self.stopped = True

    def safety_state(self) -> str:
        return self._fault

    def reported_tcp_position(self) -> np.ndarray:
        """The TCP position a controller would report: the model's f(q) (the simulator has no other)."""
        return self.kinematics.forward(self.arm.joint_state()[0])

    def speed_scaling(self) -> float:
        """Speed slider of the rehearsal: always 100 %."""
        return 1.0

    def unlock_protective_stop(self) -> str | None:
        """The dashboard's unlock: releases a protective stop (``None``), else the controller's refusal."""
        if self._fault != PROTECTIVE_STOP:
            return "Cannot unlock protective stop"
        self._fault = NORMAL
        return None

    def inject_fault(self, state: str) -> None:
        """Make the controller report ``state`` (``protective_stop`` or ``emergency_stop``) from now on."""
        if state not in (PROTECTIVE_STOP, EMERGENCY_STOP, NORMAL):
            raise ValueError(f"unknown safety state {state!r}")
        self._fault = state
        if state != NORMAL:
            self.arm.command_velocities(np.zeros(self.kinematics.n_joints))

    def close(self) -> None:
        if self.sim.client >= 0:
            self.stop()
            self.sim.close()


class DryRunConnection:
    """Wraps a connection: reads its state and keeps its timing, but sends nothing.

    Every command that would have been sent is kept in :attr:`sent` (and printed through
    ``echo`` when given), so a dry run shows exactly what a real run would stream.
    """

    def __init__(self, inner: ArmConnection, echo: object = None) -> None:
        self.inner = inner
        self.kinematics = inner.kinematics
        self.dt = inner.dt
        self.sent: list[np.ndarray] = []
        self._echo = echo

    def read_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self.inner.read_state()

    def start_period(self) -> float:
        return self.inner.start_period()

    def command(self, velocities: np.ndarray) -> None:
        self.sent.append(np.array(velocities, dtype=float))
        if callable(self._echo):
            self._echo(f"would send speedJ {np.array2string(np.asarray(velocities), precision=4, separator=', ')}")

    def end_period(self, period_start: float) -> None:
        self.inner.end_period(period_start)  # no command was sent: the arm holds still meanwhile

    def stop(self) -> None:
        pass  # nothing was sent, so nothing moves

    def move_to(self, q: np.ndarray) -> None:
        if callable(self._echo):
            self._echo(f"would moveJ to {np.round(np.asarray(q), 4).tolist()}")

    def state_timestamp(self) -> float:
        return self.inner.state_timestamp()

    def safety_state(self) -> str:
        return self.inner.safety_state()

    def __getattr__(self, name: str) -> object:
        if name in ("reported_tcp_position", "speed_scaling"):  # optional reads of the inner connection
            return getattr(self.inner, name)
        raise AttributeError(name)

    def close(self) -> None:
        self.inner.close()
