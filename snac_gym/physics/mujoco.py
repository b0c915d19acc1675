"""The arm in MuJoCo (``physics="mujoco"``): the same URDF, velocity servos, and a headless scene.

:class:`MuJoCoArm` steps the model of :func:`snac_gym.physics.mujoco_model.build_physics_spec`: each
control period holds the command on the joints' velocity servos for ``n_substeps`` physics steps
of the implicit-fast integrator. :class:`MuJoCoScene` draws what the PyBullet scene draws
(:mod:`snac_gym.physics.scene`: floor, two-colour links, target, ellipse path, sample cuboid) through
the same camera, with MuJoCo's OpenGL renderer on a headless context: EGL (a GPU, or Mesa's
software EGL) or OSMesa, whichever works first (``MUJOCO_GL=egl`` or ``osmesa`` picks one).

Needs ``mujoco`` (the ``mujoco`` extra).
"""

from __future__ import annotations

import copy
import importlib
import math
import os
from typing import Any

import numpy as np

from snac_gym.common.extras import require
from snac_gym.model.kinematics import Kinematics
from snac_gym.physics.base import check_image_size, check_timing
from snac_gym.physics.mujoco_model import EE_SITE, build_physics_spec
from snac_gym.physics.scene import (
    CUBOID_COLOUR,
    FIELD_OF_VIEW,
    FLOOR_COLOUR,
    FLOOR_HALF_EXTENTS,
    LINK_COLOURS,
    PARKED,
    PATH_COLOUR,
    PATH_POINTS,
    PATH_RADIUS,
    TARGET_COLOUR,
    TARGET_RADIUS,
    CameraOptions,
    base_yaw,
    cuboid_edges,
    fit_camera,
    framing_configurations,
    framing_corners,
    path_positions,
)
from snac_gym.references import Reference
from snac_gym.sampling import SampleSpace, nominal_configuration

mujoco: Any = require("mujoco", "mujoco", "physics='mujoco'")

#: Headless OpenGL platforms tried, in order, when ``MUJOCO_GL`` does not name one.
GL_PLATFORMS = ("egl", "osmesa")
#: Name of the camera the scene adds.
CAMERA = "scene"


class MuJoCoArm:
    """The URDF in MuJoCo, each period ``n_substeps`` physics steps under velocity servos.

    Each joint stops at its URDF position limit: the command is cut to the speed that reaches the
    limit in one period (MuJoCo's soft limit constraint is off, see
    :func:`~snac_gym.physics.mujoco_model.build_physics_spec`), as a UR controller's joint-limit protection
    stops the joint.

    Args:
        kinematics: The shared kinematics (gives the URDF and the joint order).
        dt: Control period, s.
        n_substeps: Physics steps per period.
    """

    def __init__(self, kinematics: Kinematics, dt: float, n_substeps: int) -> None:
        self.dt, self.n_substeps = check_timing(dt, n_substeps)
        self.kinematics = kinematics
        self.spec = build_physics_spec(kinematics, self.dt / self.n_substeps)
        self._lower, self._upper = kinematics.lower_limits, kinematics.upper_limits
        self._compile()

    def _compile(self) -> None:
        self.model = self.spec.compile()
        self.data = mujoco.MjData(self.model)
        self.reset(nominal_configuration(self.kinematics))

    def replica(self) -> MuJoCoArm:
        """Another arm on this arm's compiled model, with its own ``MjData``, at the nominal pose: the
        same physics at a fraction of a compile (the lockstep engine holds one per sample)."""
        arm = copy.copy(self)
        arm.data = mujoco.MjData(self.model)
        arm.reset(nominal_configuration(self.kinematics))
        return arm

    def add_to_world(self, build: Any) -> None:
        """Let ``build(spec)`` add bodies to the world (the scene's), and recompile; before the first reset."""
        build(self.spec)
        self._compile()

    def save_initial_state(self) -> None:
        """Nothing to save: every reset starts from MuJoCo's reset state (kept for the arm protocol)."""

    def reset(self, q0: np.ndarray) -> None:
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = q0
        mujoco.mj_forward(self.model, self.data)

    def apply(self, u: np.ndarray) -> None:
        q = self.data.qpos
        self.data.ctrl[:] = np.minimum(np.maximum(u, (self._lower - q) / self.dt), (self._upper - q) / self.dt)
        mujoco.mj_step(self.model, self.data, self.n_substeps)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self.data.qpos.copy(), self.data.qvel.copy()

    def restore(self, q: np.ndarray, qdot: np.ndarray, command: np.ndarray) -> None:
        self.reset(q)
        self.data.qvel[:] = qdot
        self.data.ctrl[:] = command
        mujoco.mj_forward(self.model, self.data)

    def ee_world_position(self) -> np.ndarray:
        """End-effector position (world frame) from MuJoCo's own site, for checking the kinematics."""
        mujoco.mj_kinematics(self.model, self.data)
        return self.data.site(EE_SITE).xpos.copy()

    def close(self) -> None:
        pass

    def scene(
        self, kinematics: Kinematics, space: SampleSpace, width: int, height: int, camera: CameraOptions | None = None
    ) -> MuJoCoScene:
        """What a frame of this arm shows (drawn by MuJoCo's renderer)."""
        return MuJoCoScene(self, kinematics, space, width, height, camera)


def _context_class(platform: str) -> Any:
    """MuJoCo's ``GLContext`` class of ``platform`` (``"egl"`` or ``"osmesa"``); importing it loads the library."""
    return importlib.import_module(f"mujoco.{platform}").GLContext


def gl_context(width: int, height: int) -> Any:
    """A current headless OpenGL context of MuJoCo's: ``MUJOCO_GL``'s platform, else the first of
    :data:`GL_PLATFORMS` that works.

    Raises:
        RuntimeError: Naming each platform tried and why it failed, and what to install.
    """
    chosen = os.environ.get("MUJOCO_GL", "").strip().lower()
    platforms = (chosen,) if chosen in GL_PLATFORMS else GL_PLATFORMS
    failures = []
    for platform in platforms:
        try:
            context = _context_class(platform)(width, height)
            context.make_current()
            return context
        except Exception as exc:  # noqa: BLE001 - any failure means: try the next platform
            failures.append(f"{platform}: {type(exc).__name__}: {str(exc).strip() or 'failed'}")
    raise RuntimeError(
        "physics='mujoco' renders headless through EGL or OSMesa and neither works here ("
        + "; ".join(failures)
        + "); install libegl1 (or a GPU driver) or libosmesa6, or set MUJOCO_GL=egl|osmesa to pick one"
    )


class MuJoCoScene:
    """The rendered world of one MuJoCo env: what :class:`~snac_gym.physics.bullet.PyBulletScene` draws, in MuJoCo.

    The floor, the cuboid's bars, the target and the path markers are added to the arm's model
    (markers as mocap bodies, moved without touching the physics); the links alternate the two
    link colours; the camera is :func:`~snac_gym.physics.scene.fit_camera`'s.

    Args:
        arm: The env's arm (its model is recompiled with the scene).
        kinematics: The shared kinematics (base frame ↔ world frame).
        space: The sample cuboid the camera must show.
        width, height: Image size, pixels.

    Raises:
        RuntimeError: If no headless OpenGL platform works (:func:`gl_context`).
    """

    def __init__(
        self,
        arm: MuJoCoArm,
        kinematics: Kinematics,
        space: SampleSpace,
        width: int,
        height: int,
        camera: CameraOptions | None = None,
    ) -> None:
        self.arm, self.kinematics = arm, kinematics
        self.width, self.height = check_image_size(width, height)
        self._arm_bodies = list(range(1, arm.model.nbody))  # the world body is 0; the scene's come after
        self.camera = fit_camera(
            self.framed_points(space), kinematics, self.width, self.height, camera, self.start_points(space)
        )
        self.view, self.projection = self.camera.view, self.camera.projection
        arm.add_to_world(lambda spec: self._build(spec, space))
        model = arm.model
        self._target = int(model.body_mocapid[model.body("target").id])
        self._path = [int(model.body_mocapid[model.body(f"path{i}").id]) for i in range(PATH_POINTS)]
        self._context = gl_context(self.width, self.height)
        self._render_context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._render_context)
        self._scene = mujoco.MjvScene(model, maxgeom=model.ngeom + 16)
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = model.camera(CAMERA).id
        self._options = mujoco.MjvOption()
        self._viewport = mujoco.MjrRect(0, 0, self.width, self.height)
        self._rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)

    # -- building ------------------------------------------------------------------------------
    def _build(self, spec: Any, space: SampleSpace) -> None:
        spec.visual.global_.offwidth = max(self.width, 1)
        spec.visual.global_.offheight = max(self.height, 1)
        spec.visual.headlight.ambient = [0.45, 0.45, 0.45]
        for index, body in enumerate(spec.bodies):  # the world body (holding the base's mesh), then the links
            for geom in body.geoms:
                geom.rgba = LINK_COLOURS[index % len(LINK_COLOURS)]
        spec.add_texture(
            name="sky",
            type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
            builtin=mujoco.mjtBuiltin.mjBUILTIN_FLAT,
            rgb1=[1.0, 1.0, 1.0],
            rgb2=[1.0, 1.0, 1.0],
            width=8,
            height=8,
        )
        world = spec.worldbody
        world.add_light(pos=[0.0, 0.0, 4.0], dir=[-0.4, 0.4, -1.0], diffuse=[0.5, 0.5, 0.5], castshadow=False)
        box, sphere = mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_SPHERE
        world.add_geom(type=box, size=list(FLOOR_HALF_EXTENTS), pos=[0, 0, -FLOOR_HALF_EXTENTS[2]], rgba=FLOOR_COLOUR)
        yaw = base_yaw(self.kinematics)
        orientation = [math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0)]
        for corner, extents in cuboid_edges(space):
            world.add_geom(
                type=box,
                size=extents.tolist(),
                pos=self.kinematics.base_to_world(corner).tolist(),
                quat=orientation,
                rgba=CUBOID_COLOUR,
            )
        markers = [("target", TARGET_RADIUS, TARGET_COLOUR)]
        markers += [(f"path{i}", PATH_RADIUS, PATH_COLOUR) for i in range(PATH_POINTS)]
        for name, radius, colour in markers:
            marker = world.add_body(name=name, mocap=True, pos=list(PARKED))
            marker.add_geom(type=sphere, size=[radius, 0, 0], rgba=colour, contype=0, conaffinity=0)
        forward = self.camera.target - self.camera.eye
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        up /= np.linalg.norm(up)
        world.add_camera(
            name=CAMERA, pos=self.camera.eye.tolist(), fovy=FIELD_OF_VIEW, xyaxes=[*right.tolist(), *up.tolist()]
        )

    def framed_points(self, space: SampleSpace) -> np.ndarray:
        """World points the camera must show: the cuboid's corners, the base, and the body origins at the
        robot's nominal (elbow-up) pose, as
        :meth:`PyBulletScene.framed_points <snac_gym.physics.bullet.PyBulletScene.framed_points>`."""
        corners = [self.kinematics.base_to_world(c) for c in framing_corners(space)]
        self.arm.reset(nominal_configuration(self.kinematics))
        return np.vstack([corners, [[0.0, 0.0, 0.0]], self.link_origins()])

    def start_points(self, space: SampleSpace) -> np.ndarray:
        """The body origins at start poses as ``reset`` draws them (:func:`framing_configurations`), for
        :func:`fit_camera`'s ``also``; the arm is left at its nominal pose, as :meth:`framed_points` leaves it."""
        starts = []
        for pose in framing_configurations(self.kinematics, space):
            self.arm.reset(pose)
            starts.append(self.link_origins())
        self.arm.reset(nominal_configuration(self.kinematics))
        return np.vstack(starts)

    def link_origins(self) -> np.ndarray:
        """World positions of every body frame of the arm (MuJoCo fuses the URDF's fixed links)."""
        mujoco.mj_kinematics(self.arm.model, self.arm.data)
        return self.arm.data.xpos[self._arm_bodies].copy()

    # -- per episode and per frame ---------------------------------------------------------------
    def show_reference(self, reference: Reference) -> None:
        """Draw the episode's reference path (the ellipse; nothing for a fixed target)."""
        for mocap, position in zip(
            self._path, path_positions(reference, self.kinematics, len(self._path)), strict=True
        ):
            self.arm.data.mocap_pos[mocap] = position

    def image(self, reference_point: np.ndarray) -> np.ndarray:
        """An RGB image ``(height, width, 3)`` with the target marker at ``reference_point`` (base frame)."""
        model, data = self.arm.model, self.arm.data
        data.mocap_pos[self._target] = self.kinematics.base_to_world(reference_point)
        mujoco.mj_kinematics(model, data)  # the poses of the current state (mj_step leaves the previous ones)
        self._context.make_current()
        mujoco.mjv_updateScene(model, data, self._options, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene)
        mujoco.mjr_render(self._viewport, self._scene, self._render_context)
        mujoco.mjr_readPixels(self._rgb, None, self._viewport, self._render_context)
        return np.flipud(self._rgb).copy()  # OpenGL's rows run bottom-up

    def close(self) -> None:
        context, self._context = getattr(self, "_context", None), None
        if context is not None:
            self._render_context.free()
            context.free()
