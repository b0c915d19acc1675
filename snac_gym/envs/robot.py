"""The simulated arm: joint-velocity motors on the URDF that the shared kinematics loads."""

from __future__ import annotations

import re

import numpy as np

from snac_gym.envs.sim import PyBulletSim, p
from snac_gym.kinematics import Kinematics, resolved_urdf_text


def without_meshes(urdf: str) -> str:
    """``urdf`` without its ``<visual>`` and ``<collision>`` elements: the same links, joints and inertias.

    Loading the UR10's meshes costs PyBullet about 0.5 s and 25 MB per body; a body that is never drawn
    and never collides (every :class:`SimulatedArm` has collisions off) moves the same without them,
    as its inertias come from the URDF (``URDF_USE_INERTIA_FROM_FILE``), not from the shapes.
    """
    return re.sub(r"<(visual|collision)\b.*?</\1>", "", urdf, flags=re.S)


class SimulatedArm:
    """A URDF arm in a :class:`PyBulletSim`, driven by ``VELOCITY_CONTROL`` motors.

    Joints are matched to :attr:`Kinematics.joint_names` by name, so the simulator and the
    kinematics agree on joint order for any robot.

    Args:
        sim: The physics client.
        kinematics: The shared kinematics (gives the URDF and the joint order).
        meshes: Load the URDF's visual and collision meshes (``False``: :func:`without_meshes`, for
            bodies that are never rendered, e.g. the evaluator's lockstep arms).
    """

    def __init__(self, sim: PyBulletSim, kinematics: Kinematics, meshes: bool = True) -> None:
        self.sim = sim
        self.kinematics = kinematics
        urdf = resolved_urdf_text(kinematics.urdf_path)
        if not meshes:
            urdf = without_meshes(urdf)
        # Merging the massless fixed links (world, base, ee_link, tool0) cuts a physics step by ~20%
        # without changing the motion (see the substep study in snac_gym/bench.py).
        self.body = sim.load_urdf_text(urdf, flags=p.URDF_USE_INERTIA_FROM_FILE | p.URDF_MERGE_FIXED_LINKS)
        client = sim.client
        by_name: dict[str, int] = {}
        for index in range(p.getNumJoints(self.body, physicsClientId=client)):
            info = p.getJointInfo(self.body, index, physicsClientId=client)
            by_name[info[1].decode()] = index
        missing = [name for name in kinematics.joint_names if name not in by_name]
        if missing:
            raise ValueError(f"joints {missing} of the kinematics are not in the simulated URDF")
        self.joint_indices = [by_name[name] for name in kinematics.joint_names]
        # tool0 is merged into its parent link: keep that link and the fixed offset from the URDF.
        parent_joint, self.ee_offset = kinematics.ee_mount()
        self.ee_link = by_name[parent_joint]
        self.max_forces = [p.getJointInfo(self.body, i, physicsClientId=client)[10] for i in self.joint_indices]
        for link in range(-1, p.getNumJoints(self.body, physicsClientId=client)):
            # PyBullet's default link damping would make the motors fight a drag no real arm has.
            p.changeDynamics(self.body, link, linearDamping=0.0, angularDamping=0.0, physicsClientId=client)
            # The world holds nothing else and self-collision is off (as on the UR controller, whose
            # safety limits are joint and Cartesian, not geometric): skip the broadphase entirely.
            p.setCollisionFilterGroupMask(self.body, link, 0, 0, physicsClientId=client)

    def set_joint_positions(self, q: np.ndarray, qdot: np.ndarray | None = None) -> None:
        """Teleport the joints to ``q`` (at rest unless ``qdot`` is given), after restoring the saved state."""
        qdot = np.zeros(len(self.joint_indices)) if qdot is None else qdot
        for index, angle, rate in zip(self.joint_indices, q, qdot):
            p.resetJointState(self.body, index, float(angle), float(rate), physicsClientId=self.sim.client)

    def command_velocities(self, u: np.ndarray) -> None:
        """Set the motors' target joint velocities (rad/s), each bounded by its URDF effort."""
        p.setJointMotorControlArray(
            self.body,
            self.joint_indices,
            p.VELOCITY_CONTROL,
            targetVelocities=u.tolist(),
            forces=self.max_forces,
            physicsClientId=self.sim.client,
        )

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured ``(θ, θ̇)``."""
        states = p.getJointStates(self.body, self.joint_indices, physicsClientId=self.sim.client)
        # Two flat arrays straight from the tuples: a third cheaper than one (m, 2) array and two
        # column copies (14 -> 9.6 µs of a ~130 µs env step), and the same floats.
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])

    def ee_world_position(self) -> np.ndarray:
        """End-effector position (world frame) from PyBullet's own link state, for checking the kinematics."""
        state = p.getLinkState(self.body, self.ee_link, computeForwardKinematics=True, physicsClientId=self.sim.client)
        rotation = np.array(p.getMatrixFromQuaternion(state[5])).reshape(3, 3)
        return np.array(state[4]) + rotation @ self.ee_offset
