"""The connections that move no real arm: the PyBullet arm run in wall-clock time (a rehearsal of the whole
real-robot loop) and the dry run, which reads a connection's state but sends nothing."""

from __future__ import annotations

import time

import numpy as np

from snac_gym.model.kinematics import Kinematics
from snac_gym.physics.bullet import PyBulletSim, SimulatedArm
from snac_gym.real.protocol import EMERGENCY_STOP, NORMAL, PROTECTIVE_STOP, ArmConnection, wait_until
from snac_gym.sampling import nominal_configuration

__all__ = ["DryRunConnection", "SimulatedConnection"]


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
