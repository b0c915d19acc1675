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
        meshes: Load the URDF's meshes; ``False`` for an arm that is never drawn: it moves the same
            (:func:`~snac_gym.envs.robot.without_meshes`) and loads in milliseconds instead of 0.3 s.
    """

    def __init__(self, kinematics: Kinematics, dt: float, n_substeps: int, gui: bool = False, meshes: bool = True) -> None:
        self.sim = PyBulletSim(dt, n_substeps, gui=gui)
        self.dt = self.sim.dt
        self.body = SimulatedArm(self.sim, kinematics, meshes=meshes or gui)
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


class ArmBatch(Protocol):
    """B arms stepped together, one command row each: what the evaluator's lockstep engine drives
    (:func:`snac_gym.rollout.simulate_arms`)."""

    def __len__(self) -> int:
        """B."""

    def reset(self, q0: np.ndarray) -> None:
        """Pose arm i at row i of ``q0`` ``(B, m)``, at rest."""

    def apply(self, commands: np.ndarray) -> None:
        """Hold row i of ``commands`` ``(B, m)`` on arm i for one control period."""

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured ``(θ, θ̇)`` of all arms, ``(B, m)`` each."""

    def close(self) -> None:
        """Release the simulators."""


def _stacked(states: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """``(θ, θ̇)`` of each arm → ``(B, m)`` θ and ``(B, m)`` θ̇."""
    return np.array([q for q, _ in states]), np.array([qdot for _, qdot in states])


class ArmList:
    """An :class:`ArmBatch` of independent :class:`Arm` objects (e.g. MuJoCo replicas), stepped one by one."""

    def __init__(self, arms: list[Arm]) -> None:
        self.arms = list(arms)

    def __len__(self) -> int:
        return len(self.arms)

    def reset(self, q0: np.ndarray) -> None:
        for arm, row in zip(self.arms, q0, strict=True):
            arm.reset(row)

    def apply(self, commands: np.ndarray) -> None:
        for arm, command in zip(self.arms, commands, strict=True):
            arm.apply(command)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        return _stacked([arm.joint_state() for arm in self.arms])

    def close(self) -> None:
        for arm in self.arms:
            arm.close()


class PyBulletArmBatch:
    """B copies of the URDF in PyBullet worlds of at most ``world_size`` bodies, each world stepped by
    one ``stepSimulation`` per period.

    Each body is a :class:`~snac_gym.envs.robot.SimulatedArm` with collisions off, so the bodies never
    interact and each moves as the env's single arm does (to 1e-12 in ``tests/test_engines.py``);
    they are loaded without meshes (:func:`~snac_gym.envs.robot.without_meshes`), as nothing here is
    drawn: a few ms per body instead of a physics server of its own (0.6 s, 65 MB). A world's step
    costs more per body as it fills: a rollout step took 160, 136, 164, 187 and 309 µs per sample with
    worlds of 1, 10, 25, 50 and 100 bodies here (200 samples, DLS), hence :attr:`WORLD_SIZE`.

    Args:
        kinematics: The shared kinematics (gives the URDF and the joint order).
        dt: Control period, s.
        n_substeps: Physics steps per period.
        count: B.
        world_size: Bodies per PyBullet world.
    """

    #: Bodies per world (``docs/physics.md``: the lockstep PyBullet engine).
    WORLD_SIZE = 10

    def __init__(self, kinematics: Kinematics, dt: float, n_substeps: int, count: int, world_size: int = WORLD_SIZE) -> None:
        if count < 1 or world_size < 1:
            raise ValueError(f"count and world_size must be at least 1, got {count} and {world_size}")
        self.sims = [PyBulletSim(dt, n_substeps) for _ in range(0, count, world_size)]
        self.dt = self.sims[0].dt
        #: Body i is sample i, in world i // world_size.
        self.bodies = [SimulatedArm(self.sims[i // world_size], kinematics, meshes=False) for i in range(count)]
        self._initial_states = [sim.save_state() for sim in self.sims]

    def __len__(self) -> int:
        return len(self.bodies)

    def reset(self, q0: np.ndarray) -> None:
        for sim, state in zip(self.sims, self._initial_states, strict=True):
            sim.restore_state(state)
        for body, row in zip(self.bodies, q0, strict=True):
            body.set_joint_positions(row)

    def apply(self, commands: np.ndarray) -> None:
        for body, command in zip(self.bodies, commands, strict=True):
            body.command_velocities(command)
        for sim in self.sims:
            sim.step()

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        return _stacked([body.joint_state() for body in self.bodies])

    def close(self) -> None:
        for sim in self.sims:
            sim.close()


def make_arm(
    physics: str, kinematics: Kinematics, dt: float, n_substeps: int, gui: bool = False, meshes: bool = True
) -> Arm:
    """The arm of ``physics`` (one of :data:`PHYSICS`); ``meshes=False`` for a PyBullet arm that is never drawn.

    Raises:
        ValueError: On an unknown model.
        MissingExtraError: For ``"mujoco"`` without mujoco installed.
    """
    if physics == "pybullet":
        return PyBulletArm(kinematics, dt, n_substeps, gui=gui, meshes=meshes)
    if physics == "kinematic":
        return KinematicArm(kinematics, dt)
    if physics == "mujoco":
        from snac_gym.envs.mujoco_sim import MuJoCoArm  # needs the mujoco extra

        return MuJoCoArm(kinematics, dt, n_substeps)
    raise ValueError(f"physics must be one of {PHYSICS}, got {physics!r}")
