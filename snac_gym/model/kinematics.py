"""Position kinematics of a serial arm, loaded from a maintained URDF with Pinocchio.

This is the project's single source of forward kinematics and Jacobians: the
environments, every controller and the evaluator call an instance of
:class:`Kinematics`; nothing else computes ``f(θ)`` or ``J(θ)``.

Task coordinates are the position of an end-effector frame (``tool0`` for the UR
arms) expressed in a base frame (``base`` for the UR arms, the frame the UR
pendant shows, rotated π about z from the URDF's ``base_link``), so the paper's
numbers (seed pose, target, circle centre) work unchanged.

The parts: :mod:`~snac_gym.model.urdf` (the robots' URDF files), :mod:`~snac_gym.model.chains` (the batched chains
behind f and J), :mod:`~snac_gym.model.position_kinematics` (:class:`Kinematics`) and
:mod:`~snac_gym.model.pose_kinematics` (:class:`PoseKinematics`), all importable from here.
"""

from __future__ import annotations

from snac_gym.model.chains import BatchChain, PositionChain, leaf_chain
from snac_gym.model.pose_kinematics import PoseKinematics, shared_pose_kinematics
from snac_gym.model.position_kinematics import (
    Kinematics,
    damped_least_squares,
    damped_resolve_rows,
    joint_path,
    joint_step,
    shared_kinematics,
)
from snac_gym.model.urdf import resolved_urdf_text, robot_urdf_path, robots_directory

__all__ = [
    "BatchChain",
    "Kinematics",
    "PoseKinematics",
    "PositionChain",
    "damped_least_squares",
    "damped_resolve_rows",
    "joint_path",
    "joint_step",
    "leaf_chain",
    "resolved_urdf_text",
    "robot_urdf_path",
    "robots_directory",
    "shared_kinematics",
    "shared_pose_kinematics",
]
