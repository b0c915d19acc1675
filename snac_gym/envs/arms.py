"""What the env core drives: an arm that holds a joint-velocity command for one control period.

:class:`PyBulletArm` simulates the URDF with PyBullet's velocity motors (the default);
:class:`KinematicArm` integrates the paper's model exactly, θₖ₊₁ = θₖ + uₖΔt (eq. 3, the
evaluator's kinematic engine), thousands of times faster; :class:`~snac_gym.envs.mujoco_sim.MuJoCoArm`
simulates the same URDF in MuJoCo with velocity servos (the ``mujoco`` extra). The env's
``physics=`` argument picks one. The real robot's connections (:mod:`snac_gym.real.connections`) follow the same idea with a
wall clock behind them.
"""

from __future__ import annotations

import math
from typing import Protocol, runtime_checkable

import numpy as np

from snac_gym.envs.robot import SimulatedArm
from snac_gym.envs.sim import MAX_DT, PyBulletSim
from snac_gym.kinematics import Kinematics, joint_step

#: The arm models of the simulated envs (``physics=`` of ``gym.make``).
PHYSICS = ("pybullet", "kinematic", "mujoco")


@runtime_checkable
class Arm(Protocol):
    """A joint-velocity-controlled arm stepped one control period at a time."""

    dt: float

    def reset(self, q0: np.ndarray) -> None:
        """Pose the joints at ``q0``, at rest, with no command held."""

    def apply(self, u: np.ndarray) -> None:
        """Hold the command ``u`` (rad/s) for one control period."""

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured ``(θ, θ̇)``."""

    def restore(self, q: np.ndarray, qdot: np.ndarray, command: np.ndarray) -> None:
        """Put a pickled episode back: the joints at ``(q, qdot)`` holding ``command``."""

    def close(self) -> None:
        """Release the simulator (safe to call twice)."""


class PyBulletArm:
    """The URDF in PyBullet, each period ``n_substeps`` physics steps under velocity motors.

    Args:
        kinematics: The shared kinematics (gives the URDF and the joint order).
        dt: Control period, s.
        n_substeps: Physics steps per period.
        gui: Open the PyBullet GUI (needs a display).
    """

    def __init__(self, kinematics: Kinematics, dt: float, n_substeps: int, gui: bool = False) -> None:
        self.sim = PyBulletSim(dt, n_substeps, gui=gui)
        self.dt = self.sim.dt
        self.body = SimulatedArm(self.sim, kinematics)
        self.save_initial_state()

    def save_initial_state(self) -> None:
        """Save the world as it is now (the arm at its load pose) as the state every reset restores;
        called again after visual-only bodies (the rendered scene) are added."""
        self._initial_state = self.sim.save_state()

    def reset(self, q0: np.ndarray) -> None:
        # Restoring the saved state clears velocities, motor targets and solver caches, so an
        # episode does not depend on the one before.
        self.sim.restore_state(self._initial_state)
        self.body.set_joint_positions(q0)

    def apply(self, u: np.ndarray) -> None:
        self.body.command_velocities(u)
        self.sim.step()

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self.body.joint_state()

    def restore(self, q: np.ndarray, qdot: np.ndarray, command: np.ndarray) -> None:
        self.sim.restore_state(self._initial_state)
        self.body.set_joint_positions(q, qdot)
        self.body.command_velocities(command)

    def close(self) -> None:
        self.sim.close()


class KinematicArm:
    """The paper's kinematic model, integrated exactly: θₖ₊₁ = θₖ + uₖΔt, θ̇ = the held command.

    This is what the evaluator's kinematic engine steps (:func:`snac_gym.rollout.simulate_kinematic`):
    the measured joint velocity is the command held over the previous period (zero at the
    start); joint position limits are not enforced, as in the paper's model.
    """

    def __init__(self, kinematics: Kinematics, dt: float) -> None:
        if not (math.isfinite(dt) and 0 < dt <= MAX_DT):
            raise ValueError(f"dt must be positive, finite and at most {MAX_DT:g} s, got {dt}")
        self.dt = float(dt)
        self._q = np.zeros(kinematics.n_joints)
        self._qdot = np.zeros(kinematics.n_joints)

    def reset(self, q0: np.ndarray) -> None:
        self._q = np.array(q0, dtype=float)
        self._qdot = np.zeros_like(self._q)

    def apply(self, u: np.ndarray) -> None:
        self._q = joint_step(self._q, u, self.dt)
        self._qdot = np.array(u, dtype=float)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self._q.copy(), self._qdot.copy()

    def restore(self, q: np.ndarray, qdot: np.ndarray, command: np.ndarray) -> None:
        self._q, self._qdot = np.array(q, dtype=float), np.array(qdot, dtype=float)

    def close(self) -> None:
        pass


def make_arm(physics: str, kinematics: Kinematics, dt: float, n_substeps: int, gui: bool = False) -> Arm:
    """The arm of ``physics`` (one of :data:`PHYSICS`).

    Raises:
        ValueError: On an unknown model.
        MissingExtraError: For ``"mujoco"`` without mujoco installed.
    """
    if physics == "pybullet":
        return PyBulletArm(kinematics, dt, n_substeps, gui=gui)
    if physics == "kinematic":
        return KinematicArm(kinematics, dt)
    if physics == "mujoco":
        from snac_gym.envs.mujoco_sim import MuJoCoArm  # needs the mujoco extra

        return MuJoCoArm(kinematics, dt, n_substeps)
    raise ValueError(f"physics must be one of {PHYSICS}, got {physics!r}")
