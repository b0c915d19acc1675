"""Connections to the arm for the real-robot env: the ur_rtde connection here; the protocol they follow
(:mod:`~snac_gym.real.protocol`), the ur_rtde client's process (:mod:`~snac_gym.real.client_process`), the
dashboard's confirmation of rest (:mod:`~snac_gym.real.dashboard`), and the wall-clock simulated arm for rehearsal
and the dry-run wrapper that reads state but sends nothing (:mod:`~snac_gym.real.simulated`), all importable from here.

A connection owns the link to the arm and the timing of one control period: the env calls
``start_period`` and ``command`` when it sends u, then ``end_period`` (which blocks until the
period is over), then ``read_state`` and ``state_timestamp``. ``stop`` must be safe to call at any
time, any number of times, and returns once the arm is at rest (or cannot be reached).
"""

from __future__ import annotations

import socket
import time
from typing import Any

import numpy as np

from snac_gym.common.errors import ConnectionFailure
from snac_gym.common.extras import require_installed
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.ur_models import SERIES_FREQUENCY  # the controller generations' rates, re-exported here
from snac_gym.real.client_process import ClientProcess
from snac_gym.real.dashboard import (
    DASHBOARD_PORT,
    DASHBOARD_REST_REQUESTS,
    HELD_ROBOT_MODES,
    ask_dashboard,
    confirm_rest_by_dashboard,
)
from snac_gym.real.protocol import (
    EMERGENCY_STOP,
    NORMAL,
    PROTECTIVE_STOP,
    PROTECTIVE_STOP_LOCKOUT,
    ArmConnection,
    wait_until,
)
from snac_gym.real.rtde_client import as_arrays
from snac_gym.real.simulated import DryRunConnection, SimulatedConnection

__all__ = [
    "DASHBOARD_PORT",
    "DASHBOARD_REST_REQUESTS",
    "EMERGENCY_STOP",
    "HELD_ROBOT_MODES",
    "NORMAL",
    "PROTECTIVE_STOP",
    "PROTECTIVE_STOP_LOCKOUT",
    "SERIES_FREQUENCY",
    "ArmConnection",
    "ClientProcess",
    "ConnectionFailure",
    "DryRunConnection",
    "SimulatedConnection",
    "URRTDEConnection",
    "ask_dashboard",
    "confirm_rest_by_dashboard",
    "probe_port",
    "wait_until",
]


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
        MissingExtraError: If ur_rtde (the ``real`` extra) is not installed.
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
        # ur_rtde is imported by the client process alone: checked here, so that a missing extra is not reported as a
        # controller that cannot be reached, or as a client that died on its import.
        require_installed("rtde_receive", "real", "--connection rtde (ur_rtde)")
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
