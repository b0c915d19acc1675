"""The emulated arm: the controller's own model (UR DH parameters) and exact kinematic integration.

The controller reports ``actual_TCP_pose`` in its **base frame** (the frame the pendant shows, the
``base`` frame of the URDF, rotated π about z from ``base_link``) as ``[x, y, z, rx, ry, rz]``:
the position of the TCP, i.e. the flange (``tool0``) moved by the TCP offset, and its orientation
as a rotation vector. The emulator computes it from Universal Robots' published DH parameters
(:func:`snac_gym.model.ur_models.flange_transform`), not from the URDF: for the CB3 arms (example-robot-data's
URDFs) the connection's FK check compares two independent models; the e-series URDFs are written from the
same DH rows, so for them it checks the frames and the tool offset, not the DH numbers.

Motion is integrated exactly (no dynamics) once per controller cycle: ``speedj`` approaches its
target speed, scaled by the speed slider, at its acceleration bound (of the leading joint, the
others scaled so that the joint-space direction holds, as UR's ``speedj`` does); ``stopj`` decelerates to
rest; ``movej`` moves all joints together on a straight line in joint space at ``v`` scaled by
the slider.
"""

from __future__ import annotations

import math

import numpy as np

from snac_gym.model.kinematics import joint_step
from snac_gym.model.ur_models import UR_MODELS, flange_transform


def pose_to_matrix(pose: np.ndarray) -> np.ndarray:
    """4×4 transform of a UR pose ``[x, y, z, rx, ry, rz]`` (rotation vector)."""
    pose = np.asarray(pose, dtype=float)
    rotvec = pose[3:]
    angle = float(np.linalg.norm(rotvec))
    matrix = np.eye(4)
    if angle > 1e-12:
        k = rotvec / angle
        skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        matrix[:3, :3] = np.eye(3) + math.sin(angle) * skew + (1 - math.cos(angle)) * skew @ skew
    matrix[:3, 3] = pose[:3]
    return matrix


def matrix_to_pose(matrix: np.ndarray) -> np.ndarray:
    """UR pose ``[x, y, z, rx, ry, rz]`` of a 4×4 transform."""
    rotation = matrix[:3, :3]
    cos_angle = min(1.0, max(-1.0, (np.trace(rotation) - 1.0) / 2.0))
    angle = math.acos(cos_angle)
    if angle < 1e-9:
        rotvec = np.zeros(3)
    elif math.pi - angle < 1e-6:  # near π: the axis from the symmetric part
        axis = np.sqrt(np.maximum((np.diag(rotation) + 1.0) / 2.0, 0.0))
        signs = np.sign([1.0, rotation[0, 1] + rotation[1, 0] or 1.0, rotation[0, 2] + rotation[2, 0] or 1.0])
        rotvec = angle * axis * signs
    else:
        axis = np.array(
            [rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0], rotation[1, 0] - rotation[0, 1]]
        )
        rotvec = angle * axis / (2.0 * math.sin(angle))
    return np.concatenate([matrix[:3, 3], rotvec])


class EmulatedArm:
    """Joint state of the emulated arm, integrated exactly each controller cycle.

    Args:
        robot: A UR model of :data:`~snac_gym.model.ur_models.UR_MODELS` (its DH rows give the TCP pose).
        q: Initial joint angles, rad.
        velocity_limits: Joint speed limits, rad/s (the controller never exceeds them).
    """

    def __init__(self, robot: str, q: np.ndarray, velocity_limits: np.ndarray) -> None:
        if robot not in UR_MODELS:
            raise ValueError(f"robot must be one of {', '.join(UR_MODELS)}, got {robot!r}")
        self.robot = robot
        self.q = np.array(q, dtype=float)
        self.qd = np.zeros_like(self.q)
        self.velocity_limits = np.asarray(velocity_limits, dtype=float)
        self.speed_target = np.zeros_like(self.q)
        self.acceleration = 1.0
        self.move_target: np.ndarray | None = None
        self.move_speed = 0.0

    def speedj(self, qd: np.ndarray, acceleration: float) -> None:
        """Stream a joint speed target (``speedj``); it holds until replaced or stopped."""
        self.move_target = None
        self.speed_target = np.clip(np.asarray(qd, dtype=float), -self.velocity_limits, self.velocity_limits)
        self.acceleration = max(float(acceleration), 1e-6)

    def stopj(self, deceleration: float) -> None:
        """Decelerate every joint to rest at ``deceleration`` rad/s²."""
        self.speedj(np.zeros_like(self.q), deceleration)

    def movej(self, q: np.ndarray, speed: float) -> None:
        """Move to ``q`` on a straight joint-space line at ``speed`` rad/s (the slowest joint's pace)."""
        self.move_target = np.array(q, dtype=float)
        self.move_speed = max(float(speed), 1e-6)
        self.speed_target = np.zeros_like(self.q)

    def at_rest(self, tol: float = 1e-9) -> bool:
        return self.move_target is None and bool(np.all(np.abs(self.qd) <= tol))

    def step(self, dt: float, scaling: float) -> None:
        """Advance one controller cycle of ``dt`` s with the speed slider at ``scaling``."""
        if self.move_target is not None:
            delta = self.move_target - self.q
            distance = float(np.max(np.abs(delta)))
            reach = self.move_speed * scaling * dt
            if distance <= reach:
                self.q, self.qd, self.move_target = self.move_target.copy(), np.zeros_like(self.q), None
            else:
                self.qd = delta / distance * self.move_speed * scaling
                self.q = joint_step(self.q, self.qd, dt)
            return
        # speedj's acceleration bounds the leading joint; the others are scaled to keep the direction.
        delta = self.speed_target * scaling - self.qd
        largest = float(np.max(np.abs(delta)))
        step = self.acceleration * dt
        self.qd = self.qd + (delta if largest <= step else delta * (step / largest))
        self.q = joint_step(self.q, self.qd, dt)

    def tcp_pose(self, tcp_offset: np.ndarray) -> np.ndarray:
        """``actual_TCP_pose``: the flange moved by ``tcp_offset``, in the base frame."""
        return matrix_to_pose(flange_transform(self.robot, self.q) @ pose_to_matrix(tcp_offset))
