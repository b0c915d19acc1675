"""A MuJoCo model of a registered robot, built in memory from the same URDF as
:class:`~snac_gym.model.kinematics.Kinematics`.

The model is for kinematics (the ``mink`` controller reads its Jacobians from it): it has the
URDF's joints, in the same order and with the same position limits, and no geometry (visual and
collision meshes are dropped, so nothing is read from disk but the URDF itself and no
``package://`` path needs resolving). Two things make it agree with :class:`Kinematics` to
rounding:

* **The world frame is the robot's base frame** (``base`` for the UR arms, π about z from the
  URDF's ``base_link``): the top-level bodies are re-placed by the inverse of the base frame's pose,
  as :class:`Kinematics` re-roots its Pinocchio model, so positions and Jacobians read in MuJoCo's
  world frame are base-frame ones.
* **A site at the controlled frame** (``tool0``, ``panda_hand_tcp``, ...), named
  :data:`EE_SITE`: MuJoCo fuses a URDF's fixed links into their parents, so the frame is
  placed on the body of the joint that carries it, at the frame's placement in that joint's frame
  (Pinocchio's ``frame.placement``): a body's frame is its URDF link frame, the joint's frame.

Joints that the robot locks (the Panda's fingers, :attr:`~snac_gym.model.robots.Robot.locked_joints`)
are removed and their bodies welded at the value :class:`Kinematics` holds them at (the neutral
value clipped to the joint's limits). ``tests/baselines/test_qp_ik.py`` checks the site's position,
orientation and Jacobian against :class:`Kinematics` and :class:`~snac_gym.model.kinematics.PoseKinematics`
at random configurations of every registered robot.

:func:`build_physics_spec` builds the arm the ``physics="mujoco"`` env simulates from the same
URDF (:mod:`snac_gym.physics.mujoco`): in the URDF's world frame, as PyBullet loads it, with the
collision meshes as geometry and velocity servos on the joints.

Needs ``mujoco`` (the ``mujoco`` extra; the ``ik`` extra brings it too, through mink).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from functools import lru_cache
from typing import Any, cast

import numpy as np
import pinocchio as pin

from snac_gym.common.extras import require
from snac_gym.model.kinematics import Kinematics, resolved_urdf_text
from snac_gym.model.robots import get_robot
from snac_gym.sampling import nominal_configuration

#: Name of the site at the controlled frame.
EE_SITE = "ee"


#: Bandwidth ω of the physics model's velocity servos, rad/s: joint i's gain is k_v,i = ω·M_ii at the
#: robot's nominal pose, so every joint settles on its command with the same time constant 1/ω
#: (0.1 ms, well inside a 2.7 ms physics step; one gain for all joints would make the wrist joints
#: ~10⁴ times stiffer than the shoulder). The implicit integrator keeps the stiff servo stable.
#: How closely it follows: ``snac-gym bench --tracking``, docs/physics.md.
SERVO_BANDWIDTH = 1.0e4


def _urdf_without_geometry(
    text: str, locked: tuple[str, ...], keep_collision: bool = False
) -> tuple[str, dict[str, float]]:
    """The URDF with every ``<visual>`` removed, and every ``<collision>`` unless ``keep_collision``, and
    the value of each locked joint (its neutral value 0 clipped to its URDF limits, as
    :func:`snac_gym.model.kinematics._locked` holds it)."""
    root = ET.fromstring(text)
    for link in root.findall("link"):
        for tag in ("visual",) if keep_collision else ("visual", "collision"):
            for element in link.findall(tag):
                link.remove(element)
    values: dict[str, float] = {}
    for joint in root.findall("joint"):
        if joint.get("name") in locked:
            limit = joint.find("limit")
            low = float(limit.get("lower", 0.0)) if limit is not None else 0.0
            high = float(limit.get("upper", 0.0)) if limit is not None else 0.0
            # the name is set: it is one of the locked joints'
            values[cast(str, joint.get("name"))] = float(np.clip(0.0, low, high)) if high > low else 0.0
    return ET.tostring(root, encoding="unicode"), values


def _quat(rotation: np.ndarray) -> np.ndarray:
    """MuJoCo's (w, x, y, z) quaternion of a rotation matrix."""
    x, y, z, w = pin.Quaternion(np.asarray(rotation, dtype=float)).coeffs()
    return np.array([w, x, y, z])


def _rotation(quat: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(quat, dtype=float) / np.linalg.norm(quat)
    return pin.Quaternion(w, x, y, z).toRotationMatrix()


def _weld_locked(mujoco: Any, spec: Any, values: dict[str, float]) -> None:
    """Remove the locked joints, moving each one's body by the joint's motion at its locked value (and the
    equality constraints MuJoCo made of a locked joint's URDF ``<mimic>``)."""
    for equality in list(spec.equalities):
        if equality.name1 in values or equality.name2 in values:
            spec.delete(equality)
    for name, value in values.items():
        joint = spec.joint(name)
        body = joint.parent
        axis = np.asarray(joint.axis, dtype=float) / np.linalg.norm(joint.axis)
        rotation = _rotation(body.quat)
        if joint.type == mujoco.mjtJoint.mjJNT_HINGE:
            body.quat = _quat(rotation @ pin.exp3(axis * value))
        elif joint.type == mujoco.mjtJoint.mjJNT_SLIDE:
            body.pos = np.asarray(body.pos, dtype=float) + rotation @ axis * value
        else:  # pragma: no cover - registered robots lock 1-DoF joints only
            raise ValueError(f"locked joint {name!r} is not a hinge or slide joint")
        spec.delete(joint)


def build_mujoco_model(kinematics: Kinematics, site: str = EE_SITE) -> Any:
    """A ``mujoco.MjModel`` of ``kinematics``' arm, in its base frame, with a site at its end-effector frame.

    Args:
        kinematics: The (position) kinematics of a registered robot; its URDF, frames and locked joints are used.
        site: Name of the site added at the end-effector frame.

    Raises:
        MissingExtraError: If mujoco is not installed.
        ValueError: If the compiled model's joints are not :class:`Kinematics`' (names, order, limits).
    """
    mujoco = require("mujoco", "ik", "the MuJoCo model (mink)")
    locked = _locked_joints(kinematics)
    text, locked_values = _urdf_without_geometry(kinematics.urdf_path.read_text(), locked)
    spec = mujoco.MjSpec.from_string(text)
    spec.compiler.boundmass = 1e-6  # links without inertia: kinematics does not need it
    spec.compiler.boundinertia = 1e-9
    _weld_locked(mujoco, spec, locked_values)

    base_from_world = pin.SE3(kinematics._base_from_world, -kinematics._base_from_world @ kinematics._base_origin)
    for body in spec.worldbody.bodies:
        placement = base_from_world * pin.SE3(_rotation(body.quat), np.asarray(body.pos, dtype=float))
        body.pos, body.quat = placement.translation, _quat(placement.rotation)

    frame = kinematics.model.frames[kinematics._ee_id]
    joint_name = str(kinematics.model.names[frame.parentJoint])
    carrier = spec.joint(joint_name).parent
    carrier.add_site(name=site, pos=frame.placement.translation.copy(), quat=_quat(frame.placement.rotation))
    model = spec.compile()
    _check_joints(model, kinematics)
    return model


def build_physics_spec(kinematics: Kinematics, timestep: float, site: str = EE_SITE) -> Any:
    """A ``mujoco.MjSpec`` of ``kinematics``' arm for simulation, to compile (a scene may be added first).

    The URDF's bodies, inertias and joints in the URDF's world frame (the frame PyBullet loads it
    in, so :meth:`Kinematics.base_to_world` places base-frame points in it), with:

    * **geometry**: the URDF's collision meshes (STL), which MuJoCo reads; the visual meshes are
      COLLADA (``.dae``), which it does not. Contacts are off (the arm touches nothing and
      self-collision is off, as in the PyBullet env);
    * **a velocity servo per joint**, τ = k_v (u − θ̇), k_v = :data:`SERVO_BANDWIDTH`·M_ii at the
      nominal pose, its force unbounded: a clamped force breaks the implicit integration of the
      servo's damping, and the servo then oscillates (the URDF's effort bounds, which PyBullet's
      motors keep, are left out);
    * **gravity compensated** on every body (as a real arm's controller does), so the servo's force
      is only what the motion needs;
    * the URDF's joint damping and friction left out (a real arm's velocity loop cancels them; here
      they would leave a steady error of b·u/k_v);
    * MuJoCo's joint-limit constraint off: it is soft, and the stiff servo would push a joint tenths of
      a radian through it (``docs/scripts/mujoco_servo_choices.py``). :class:`~snac_gym.physics.mujoco.MuJoCoArm` stops
      each joint at its limit by cutting the command instead;
    * the implicit-fast integrator at ``timestep`` and a site ``site`` at the end-effector frame.

    Raises:
        MissingExtraError: If mujoco is not installed.
    """
    mujoco = require("mujoco", "mujoco", "physics='mujoco'")

    locked = _locked_joints(kinematics)
    text, locked_values = _urdf_without_geometry(resolved_urdf_text(kinematics.urdf_path), locked, keep_collision=True)
    spec = mujoco.MjSpec.from_string(text)
    spec.compiler.discardvisual = False  # the URDF importer's default drops contact-free geoms: the scene's markers
    spec.compiler.boundmass = 1e-6  # massless URDF links (tool frames) must still compile
    spec.compiler.boundinertia = 1e-9
    _weld_locked(mujoco, spec, locked_values)
    spec.option.timestep = float(timestep)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_LIMIT
    for body in spec.bodies:
        body.gravcomp = 1.0
    for name in kinematics.joint_names:
        joint = spec.joint(name)
        for attribute in ("damping", "frictionloss", "armature"):
            setattr(joint, attribute, np.zeros_like(getattr(joint, attribute)))
        joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE
    frame = kinematics.model.frames[kinematics._ee_id]
    carrier = spec.joint(str(kinematics.model.names[frame.parentJoint])).parent
    carrier.add_site(name=site, pos=frame.placement.translation.copy(), quat=_quat(frame.placement.rotation))

    model = spec.compile()
    _check_joints(model, kinematics)
    data = mujoco.MjData(model)
    data.qpos[:] = nominal_configuration(kinematics)
    inertia = np.zeros((model.nv, model.nv))
    mujoco.mj_forward(model, data)
    mujoco.mj_fullM(model, data, inertia)
    for name, diagonal in zip(kinematics.joint_names, np.diag(inertia)):
        actuator = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        actuator.set_to_velocity(kv=SERVO_BANDWIDTH * float(diagonal))
    return spec


def _locked_joints(kinematics: Kinematics) -> tuple[str, ...]:
    """The joints :class:`Kinematics` locked: its robot's, unless it was built from another URDF."""
    try:
        return get_robot(kinematics.robot).locked_joints
    except ValueError:
        return ()


def _check_joints(model: Any, kinematics: Kinematics) -> None:
    names = tuple(model.joint(i).name for i in range(model.njnt))
    if names != kinematics.joint_names or model.nq != kinematics.n_joints or model.nv != kinematics.n_joints:
        raise ValueError(f"MuJoCo model joints {names} differ from the kinematics' {kinematics.joint_names}")
    lower = np.where(model.jnt_limited, model.jnt_range[:, 0], -np.inf)
    upper = np.where(model.jnt_limited, model.jnt_range[:, 1], np.inf)
    if not (np.allclose(lower, kinematics.lower_limits) and np.allclose(upper, kinematics.upper_limits)):
        raise ValueError(
            f"MuJoCo joint limits [{lower}, {upper}] differ from the kinematics' "
            f"[{kinematics.lower_limits}, {kinematics.upper_limits}]"
        )


def shared_mujoco_model(kinematics: Kinematics) -> Any:
    """One :func:`build_mujoco_model` per arm (URDF and frames) and process: its users only read it."""
    return _cached_model(kinematics.robot, kinematics.ee_frame, kinematics.base_frame, str(kinematics.urdf_path))


@lru_cache(maxsize=8)
def _cached_model(robot: str, ee_frame: str, base_frame: str, urdf_path: str) -> Any:
    return build_mujoco_model(Kinematics(robot, ee_frame, base_frame, urdf_path))
