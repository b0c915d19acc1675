"""Arm backends for the real-robot env: a small protocol, the ur_rtde backend, a wall-clock simulated
backend for rehearsal, and a dry-run wrapper that reads state but sends nothing.

A backend owns the connection and the timing of one control period: the env calls
``start_period`` and ``command`` when it sends u, then ``end_period`` (which blocks until the
period is over), then ``read_state`` and ``state_timestamp``. ``stop`` must be safe to call at any
time, any number of times, and returns once the arm is at rest (or cannot be reached).
"""

from __future__ import annotations

import socket
import time
from typing import Protocol, runtime_checkable

import numpy as np

from snac_gym._quiet import quiet_output
from snac_gym.kinematics import Kinematics
from snac_gym.sampling import nominal_configuration

#: Safety states a backend reports (``info["safety_state"]`` of the real env).
NORMAL = "normal"
PROTECTIVE_STOP = "protective_stop"
EMERGENCY_STOP = "emergency_stop"
#: Control rates of the UR controller generations: CB-series 125 Hz, e-Series 500 Hz.
SERIES_FREQUENCY = {"cb": 125.0, "e": 500.0}


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


class ConnectionFailure(ConnectionError):
    """The arm could not be reached, refused the connection, or dropped it mid-episode."""


@runtime_checkable
class ArmBackend(Protocol):
    """What the real-robot env needs from an arm."""

    kinematics: Kinematics
    dt: float

    def read_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured joint positions (rad) and velocities (rad/s)."""

    def start_period(self) -> float:
        """Mark the start of a control period; returns its start time (backend clock, s)."""

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


class URRTDEBackend:
    """A real UR arm through ur_rtde: ``speedJ`` streamed at the control rate.

    Each period: ``initPeriod`` → ``speedJ(u, acceleration, dt)`` → ``waitPeriod``. The
    controller-side watchdog (``setWatchdog`` on the command register, armed at the first command
    of each stream) stops the control script, and so the arm, if no command arrives for
    ``watchdog_periods`` periods; the next stream re-uploads the script (``reuploadScript``).

    Args:
        host: IP address of the UR controller.
        kinematics: Model of the arm (UR10 by default).
        frequency: Control rate, Hz: 125 for CB-series, 500 for e-Series (see ``series``).
        series: ``"cb"`` or ``"e"``; sets ``frequency`` when that is not given.
        acceleration: Joint acceleration bound passed to ``speedJ``, rad/s² (of the leading joint).
            Keep it above the safety layer's ``max_joint_acceleration``: the shaped command already
            bounds the acceleration, and a lower ramp here makes the arm trail every command
            change (:func:`~snac_gym.real.run.make_backend` passes twice the layer's bound).
        control: Open the control interface (``False`` for a dry run: state only, nothing sent).
        connect_timeout: Seconds to wait for the controller before giving up.
        watchdog_periods: Missed periods after which the controller's watchdog stops the arm.
        move_speed: Joint speed of ``move_to`` (``moveJ``), rad/s.
        stop_deceleration: Joint deceleration of ``speedStop``, rad/s².
        rest_timeout: Longest wait (s) for the arm to come to rest after ``speedStop``.

    Raises:
        ConnectionFailure: If the controller cannot be reached (within ``connect_timeout``).
    """

    RTDE_PORT = 30004

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
        self.host = host
        self._control = None
        self._receive = None
        self.stop_calls = 0
        self._streaming = False
        self._snapshot: tuple[np.ndarray, np.ndarray, np.ndarray, float, float] | None = None
        probe_port(host, self.RTDE_PORT, connect_timeout)
        try:
            import rtde_control
            import rtde_receive
        except ImportError as exc:  # pragma: no cover - depends on the install
            raise ConnectionFailure("ur_rtde is not installed: pip install 'snac-gym[real]'") from exc
        try:
            with quiet_output():
                self._receive = rtde_receive.RTDEReceiveInterface(host, self.frequency)
                if control:
                    self._control = rtde_control.RTDEControlInterface(host, self.frequency)
        except RuntimeError as exc:
            self.close()
            raise ConnectionFailure(f"ur_rtde could not connect to {host}: {str(exc).splitlines()[0]}") from exc
        self.watchdog_frequency = self.frequency / watchdog_periods

    def _link_up(self) -> bool:
        """Both ur_rtde interfaces still connected (a control call on a lost link blocks in its reconnect)."""
        receive_up = self._receive is not None and self._receive.isConnected()
        return receive_up and (self._control is None or self._control.isConnected())

    def _require_connection(self) -> None:
        if not self._link_up():
            raise ConnectionFailure(f"connection to the arm at {self.host} was lost")

    def read_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint state of one RTDE package (with its TCP pose, speed scaling and timestamp).

        ur_rtde's getters each read the latest package, which may change between two calls; the
        reads are repeated until the timestamp is the same before and after, so that q, θ̇, the
        TCP pose and the timestamp all belong to the same package.
        """
        self._require_connection()
        receive = self._receive
        for _ in range(5):
            stamp = float(receive.getTimestamp())
            q, qd = np.array(receive.getActualQ()), np.array(receive.getActualQd())
            tcp, scaling = np.array(receive.getActualTCPPose()), float(receive.getSpeedScaling())
            if float(receive.getTimestamp()) == stamp:
                break
        self._snapshot = (q, qd, tcp, scaling, stamp)
        return q.copy(), qd.copy()

    def reported_tcp_position(self) -> np.ndarray:
        """The controller's TCP position (``actual_TCP_pose[:3]``, m, UR base frame) of the last read.

        With no TCP offset set on the pendant it is the flange (``tool0``) in the ``base`` frame,
        the point and frame of :class:`~snac_gym.kinematics.Kinematics`' defaults.
        """
        return self._last_snapshot()[2][:3].copy()

    def speed_scaling(self) -> float:
        """The controller's speed scaling of the last read (the pendant's slider, 1.0 = 100 %)."""
        return self._last_snapshot()[3]

    def _last_snapshot(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
        if self._snapshot is None:
            self.read_state()
        return self._snapshot  # type: ignore[return-value]

    def _ensure_program(self) -> None:
        """Re-upload ur_rtde's control script if it is not running (the watchdog stopped it while idle).

        Raises:
            ConnectionFailure: If it does not start within ``rest_timeout`` s.
        """
        if self._control.isProgramRunning():
            return
        self._control.reuploadScript()
        deadline = time.perf_counter() + self.rest_timeout
        while not self._control.isProgramRunning():
            if time.perf_counter() > deadline:
                raise ConnectionFailure(
                    f"the control script did not start on {self.host} (is the arm in remote control?)"
                )
            time.sleep(self.dt)

    def start_period(self) -> float:
        if self._control is None:
            return time.perf_counter()
        return self._control.initPeriod()

    def command(self, velocities: np.ndarray) -> None:
        if self._control is None:
            raise RuntimeError("this backend was opened without the control interface (dry run)")
        self._require_connection()
        if not self._streaming:  # the first command after a stop: arm the watchdog for this stream
            self._ensure_program()
            self._control.setWatchdog(self.watchdog_frequency)
            self._streaming = True
        # No kickWatchdog: ur_rtde 1.6.5 sends it as input_int_register_0 = 0 (seen on the wire by
        # the emulator), which overwrites speedJ's command id 9 before the control script reads it
        # when both land in the same controller cycle. speedJ's own package refreshes the watched
        # register every period, so the watchdog is fed all the same.
        if not self._control.speedJ(list(map(float, velocities)), self.acceleration, self.dt):
            raise ConnectionFailure(f"the arm at {self.host} rejected speedJ (connection lost or program stopped)")

    def end_period(self, period_start: float) -> None:
        if self._control is None:
            wait_until(period_start + self.dt)
            return
        self._control.waitPeriod(period_start)

    def state_timestamp(self) -> float:
        return self._last_snapshot()[4]

    def stop(self) -> None:
        if self._control is None:
            return
        # Once stopped, the host goes quiet: the watchdog then ends the control script on the
        # controller, and the next stream re-uploads it and arms the watchdog again.
        self._streaming = False
        self.stop_calls += 1
        if not self._link_up():
            # ur_rtde's speedStop on a lost link tries to reconnect and can block for good (seen
            # against the emulator): with no link the controller's watchdog stops the arm instead.
            return
        try:
            self._control.speedStop(self.stop_deceleration)
        except RuntimeError:  # already disconnected: the controller's watchdog stops the arm
            return
        # speedStop returns before the arm has decelerated: wait for rest so that the next
        # episode's acceleration bound, which starts from u = 0, holds.
        deadline = time.perf_counter() + self.rest_timeout
        while time.perf_counter() < deadline:
            try:
                if self._receive is None or max(map(abs, self._receive.getActualQd())) < 1e-3:
                    return
            except RuntimeError:
                return
            time.sleep(self.dt)

    def move_to(self, q: np.ndarray) -> None:
        if self._control is None:
            raise RuntimeError("cannot move the arm in a dry run")
        self._require_connection()
        self._ensure_program()
        if not self._control.moveJ(list(map(float, q)), self.move_speed, 0.5):
            raise ConnectionFailure(f"moveJ to the start pose failed on {self.host}")

    def safety_state(self) -> str:
        self._require_connection()
        if self._receive.isEmergencyStopped():
            return EMERGENCY_STOP
        if self._receive.isProtectiveStopped():
            return PROTECTIVE_STOP
        return NORMAL

    def close(self) -> None:
        self.stop()
        if self._control is not None:
            try:
                if self._link_up():
                    self._control.stopScript()
                self._control.disconnect()
            except RuntimeError:
                pass
            self._control = None
        if self._receive is not None:
            try:
                self._receive.disconnect()
            except RuntimeError:
                pass
            self._receive = None


class SimulatedBackend:
    """The PyBullet UR arm behind the backend protocol, run in wall-clock time.

    ``end_period`` steps the physics by one period and then sleeps until the period's end, so a
    whole real-robot loop (policy, safety layer, timing, deadlines) is rehearsed without hardware.
    ``realtime=False`` skips the sleep (tests). ``inject_fault`` makes the next reads report a
    protective or emergency stop, as the controller would.

    Args:
        kinematics: Model of the arm (UR10 by default).
        frequency: Control rate, Hz.
        n_substeps: Physics steps per period.
        realtime: Sleep to hold the wall-clock period.
        home: Where the simulated arm is parked when the backend starts (default: the
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
        from snac_gym.envs.robot import SimulatedArm
        from snac_gym.envs.sim import PyBulletSim

        self.kinematics = kinematics if kinematics is not None else Kinematics("ur10")
        self.frequency = float(frequency)
        self.dt = 1.0 / self.frequency
        self.realtime = realtime
        self.sim = PyBulletSim(self.dt, n_substeps)
        self.arm = SimulatedArm(self.sim, self.kinematics)
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


class DryRunBackend:
    """Wraps a backend: reads its state and keeps its timing, but sends nothing.

    Every command that would have been sent is kept in :attr:`sent` (and printed through
    ``echo`` when given), so a dry run shows exactly what a real run would stream.
    """

    def __init__(self, inner: ArmBackend, echo: object = None) -> None:
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
        if name in ("reported_tcp_position", "speed_scaling"):  # optional reads of the inner backend
            return getattr(self.inner, name)
        raise AttributeError(name)

    def close(self) -> None:
        self.inner.close()
