"""The physics engines behind the simulated envs, one module each: :mod:`~snac_gym.physics.bullet` (PyBullet, the
default), :mod:`~snac_gym.physics.kinematic` (the paper's exact model) and :mod:`~snac_gym.physics.mujoco` (the
``mujoco`` extra); :mod:`~snac_gym.physics.base` holds what they share and the vocabulary (:data:`PHYSICS`),
:mod:`~snac_gym.physics.scene` the camera and what a frame shows. The real robot's connections
(:mod:`snac_gym.real.connections`) follow the same :class:`Arm` contract with a wall clock behind them.
"""

from __future__ import annotations

from snac_gym.model.kinematics import Kinematics
from snac_gym.physics.base import (
    PHYSICS,
    PYBULLET_SOLVERS,
    SIMULATED,
    Arm,
    ArmBatch,
    ArmList,
    check_physics,
    check_pybullet_solver,
    scene_of,
)
from snac_gym.physics.bullet import PyBulletArm, PyBulletArmBatch
from snac_gym.physics.kinematic import KinematicArm

__all__ = [
    "PHYSICS",
    "PYBULLET_SOLVERS",
    "SIMULATED",
    "Arm",
    "ArmBatch",
    "ArmList",
    "KinematicArm",
    "PyBulletArm",
    "PyBulletArmBatch",
    "check_physics",
    "check_pybullet_solver",
    "make_arm",
    "scene_of",
]


def make_arm(
    physics: str,
    kinematics: Kinematics,
    dt: float,
    n_substeps: int,
    gui: bool = False,
    meshes: bool = True,
    pybullet_solver: str = "pgs",
) -> Arm:
    """The arm of ``physics`` (one of :data:`PHYSICS`); ``meshes=False`` for a PyBullet arm that is never drawn,
    ``pybullet_solver`` how a PyBullet arm's motors are solved (:data:`PYBULLET_SOLVERS`, checked by the arm; the env
    checks it whatever the engine, and the other engines have none).

    Raises:
        ValueError: On an unknown model.
        MissingExtraError: For ``"mujoco"`` without mujoco installed.
    """
    check_physics(physics)
    if physics == "kinematic":
        return KinematicArm(kinematics, dt)
    if physics == "mujoco":
        from snac_gym.physics.mujoco import MuJoCoArm  # needs the mujoco extra

        return MuJoCoArm(kinematics, dt, n_substeps)
    return PyBulletArm(kinematics, dt, n_substeps, gui=gui, meshes=meshes, solver=pybullet_solver)
