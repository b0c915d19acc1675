"""The PyBullet engine: one physics client (:class:`PyBulletSim`), the arm body on it with joint-velocity motors
(:class:`SimulatedArm`), and the env-facing arms (:class:`PyBulletArm`, :class:`PyBulletArmBatch`)."""

from __future__ import annotations

import os
import re
import sys
import tempfile
from typing import Any

import numpy as np

from snac_gym.common._quiet import quiet_output
from snac_gym.model.kinematics import Kinematics, resolved_urdf_text
from snac_gym.physics.base import _stacked, check_image_size, check_pybullet_solver, check_timing
from snac_gym.physics.meshes import visual_meshes_as_obj
from snac_gym.physics.scene import (
    CUBOID_COLOUR,
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

with quiet_output():
    import pybullet as _pybullet

p: Any = _pybullet


class PyBulletSim:
    """One PyBullet client that advances by a control period split into physics substeps.

    Args:
        dt: Control period in seconds: one :meth:`step` advances the world by ``dt``.
        n_substeps: Physics steps per control period (physics step ``dt / n_substeps``).
        gui: Open the PyBullet GUI (needs a display) instead of the headless DIRECT client.
        gravity: Gravity along −z, m/s².
        solver: How the motors are solved (:data:`~snac_gym.physics.base.PYBULLET_SOLVERS`): ``"pgs"``, PyBullet's
            default, or ``"dantzig"``, its MLCP solver with Dantzig's direct pivoting.
    """

    def __init__(
        self, dt: float, n_substeps: int, gui: bool = False, gravity: float = 9.81, solver: str = "pgs"
    ) -> None:
        self.dt, self.n_substeps = check_timing(dt, n_substeps)
        check_pybullet_solver(solver)  # before the client: a bad value connects nothing
        if gui and sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
            # PyBullet would call exit() on a failed GUI connection, killing the caller.
            raise RuntimeError(
                "render_mode='human' opens the PyBullet GUI and needs a display, but DISPLAY is not set; "
                "use render_mode='rgb_array' to render headless"
            )
        with quiet_output():
            self.client = p.connect(p.GUI if gui else p.DIRECT)
        if self.client < 0:
            raise RuntimeError("could not connect to PyBullet" + (" GUI (is there a display?)" if gui else ""))
        if gui:
            p.configureDebugVisualizer(p.COV_ENABLE_GUI, 0, physicsClientId=self.client)
        # One stepSimulation call advances dt in n_substeps fixed steps: one Python call per control step.
        p.setPhysicsEngineParameter(
            fixedTimeStep=self.dt,
            numSubSteps=self.n_substeps,
            # The arm touches nothing (see SimulatedArm), so there are no contact pairs to order and no
            # friction cones to solve; both settings only cost time here.
            deterministicOverlappingPairs=0,
            enableConeFriction=0,
            physicsClientId=self.client,
        )
        p.setGravity(0.0, 0.0, -gravity, physicsClientId=self.client)
        if solver == "dantzig":
            # An iterated solve stops at a residual and leaves each motor a steady lag under gravity (the arm's weight);
            # the direct solve meets every motor below its force bound to rounding, so a joint follows θ̇ = u.
            with quiet_output():  # PyBullet prints the switch ("switched solver")
                p.setPhysicsEngineParameter(
                    constraintSolverType=p.CONSTRAINT_SOLVER_LCP_DANTZIG, physicsClientId=self.client
                )

    def load_urdf_text(self, urdf_text: str, flags: int = 0) -> int:
        """Load a URDF given as text (a temporary file is written and removed), base fixed."""
        with tempfile.NamedTemporaryFile("w", suffix=".urdf", delete=False) as handle:
            handle.write(urdf_text)
            path = handle.name
        try:
            with quiet_output():  # merging fixed links prints a trace to stdout
                return p.loadURDF(path, useFixedBase=True, flags=flags, physicsClientId=self.client)
        finally:
            os.unlink(path)

    def step(self) -> None:
        p.stepSimulation(physicsClientId=self.client)

    def save_state(self) -> int:
        return p.saveState(physicsClientId=self.client)

    def restore_state(self, state_id: int) -> None:
        p.restoreState(stateId=state_id, physicsClientId=self.client)

    def render(self, width: int, height: int, target: np.ndarray, distance: float = 2.2) -> np.ndarray:
        """An RGB image (``(height, width, 3)`` uint8) from a camera orbiting ``target``, headless-safe.

        Raises:
            ValueError: If ``width`` or ``height`` is not in [1, :data:`MAX_IMAGE_SIDE`] (:func:`check_image_size`).
        """
        width, height = check_image_size(width, height)
        view = p.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=list(target),
            distance=distance,
            yaw=45.0,
            pitch=-25.0,
            roll=0.0,
            upAxisIndex=2,
            physicsClientId=self.client,
        )
        proj = p.computeProjectionMatrixFOV(
            fov=50.0, aspect=width / height, nearVal=0.05, farVal=10.0, physicsClientId=self.client
        )
        _, _, rgba, _, _ = p.getCameraImage(
            width,
            height,
            viewMatrix=view,
            projectionMatrix=proj,
            renderer=p.ER_TINY_RENDERER,
            physicsClientId=self.client,
        )
        return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3].copy()

    def close(self) -> None:
        if self.client >= 0 and p.isConnected(self.client):
            p.disconnect(self.client)
        self.client = -1

    def __del__(self) -> None:
        # An env dropped without close() would otherwise keep its physics server (~65 MB) for the
        # life of the process: a test suite or a notebook that builds many envs runs out of memory.
        try:
            if getattr(self, "client", -1) >= 0 and p is not None and p.isConnected(self.client):
                p.disconnect(self.client)
        except Exception:  # noqa: BLE001 - interpreter shutdown may have torn pybullet down already
            pass


def without_meshes(urdf: str) -> str:
    """``urdf`` without its ``<visual>`` and ``<collision>`` elements: the same links, joints and inertias.

    Loading the UR10's meshes costs PyBullet 30-50 ms and 47 MB per body (0.2 s and 37 MB from the ``.dae`` files),
    besides the client's own 29 MB; a body that is never drawn and never collides (every :class:`SimulatedArm` has
    collisions off) moves the same without them, as its inertias come from the URDF (``URDF_USE_INERTIA_FROM_FILE``),
    not from the shapes.
    """
    return re.sub(r"<(visual|collision)\b.*?</\1>", "", urdf, flags=re.S)


class SimulatedArm:
    """A URDF arm in a :class:`PyBulletSim`, driven by ``VELOCITY_CONTROL`` motors.

    Joints are matched to :attr:`Kinematics.joint_names` by name, so the simulator and the
    kinematics agree on joint order for any robot.

    Args:
        sim: The physics client.
        kinematics: The shared kinematics (gives the URDF and the joint order).
        meshes: Load the URDF's visual meshes (from their OBJ copies, :mod:`snac_gym.physics.meshes`) and collision
            meshes (``False``: :func:`without_meshes`, for bodies that are never rendered, e.g. the evaluator's
            lockstep arms).
    """

    def __init__(self, sim: PyBulletSim, kinematics: Kinematics, meshes: bool = True) -> None:
        self.sim = sim
        self.kinematics = kinematics
        urdf = resolved_urdf_text(kinematics.urdf_path)
        # Drawn: the visuals from their OBJ copies, six times quicker to load, the same frames (physics/meshes.py).
        urdf = visual_meshes_as_obj(urdf) if meshes else without_meshes(urdf)
        # Merging the massless fixed links (world, base, ee_link, tool0) cuts a physics step by ~20%
        # without changing the motion (see the substep study in snac_gym/apps/bench.py).
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
        # Two flat arrays straight from the transposed tuples (position, velocity, reaction forces, torque
        # per joint): the same floats as one (m, 2) array's columns, at a fraction of its cost.
        positions, velocities, _, _ = zip(*states)
        return np.array(positions), np.array(velocities)

    def ee_world_position(self) -> np.ndarray:
        """End-effector position (world frame) from PyBullet's own link state, for checking the kinematics."""
        state = p.getLinkState(self.body, self.ee_link, computeForwardKinematics=True, physicsClientId=self.sim.client)
        rotation = np.array(p.getMatrixFromQuaternion(state[5])).reshape(3, 3)
        return np.array(state[4]) + rotation @ self.ee_offset


class PyBulletArm:
    """The URDF in PyBullet, each period ``n_substeps`` physics steps under velocity motors.

    Args:
        kinematics: The shared kinematics (gives the URDF and the joint order).
        dt: Control period, s.
        n_substeps: Physics steps per period.
        gui: Open the PyBullet GUI (needs a display).
        meshes: Load the URDF's meshes; ``False`` for an arm that is never drawn: it moves the same
            (:func:`~snac_gym.physics.bullet.without_meshes`) and loads in 3 ms instead of 30-50 ms (0.2 s from
            the ``.dae`` files themselves, the first time their OBJ copies are written 0.6 s).
        solver: How the motors are solved (:class:`PyBulletSim`).
    """

    def __init__(
        self,
        kinematics: Kinematics,
        dt: float,
        n_substeps: int,
        gui: bool = False,
        meshes: bool = True,
        solver: str = "pgs",
    ) -> None:
        self.sim = PyBulletSim(dt, n_substeps, gui=gui, solver=solver)
        self.dt = self.sim.dt
        self.body = SimulatedArm(self.sim, kinematics, meshes=meshes or gui)
        self.save_initial_state()

    def save_initial_state(self) -> None:
        """Save the world as it is now (the arm at its load pose) as the state every reset restores;
        called again after visual-only bodies (the rendered scene) are added."""
        self._initial_state = self.sim.save_state()

    def scene(
        self, kinematics: Kinematics, space: SampleSpace, width: int, height: int, camera: CameraOptions | None = None
    ) -> PyBulletScene:
        """What a frame of this arm shows (drawn by PyBullet's TinyRenderer)."""
        return PyBulletScene(self.sim.client, self.body.body, kinematics, space, width, height, camera)

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


class PyBulletArmBatch:
    """B copies of the URDF in PyBullet worlds of at most ``world_size`` bodies, each world stepped by
    one ``stepSimulation`` per period.

    Each body is a :class:`~snac_gym.physics.bullet.SimulatedArm` with collisions off, so the bodies never
    interact and each moves as the env's single arm does (to 1e-12 in ``tests/rollout/test_batch.py``);
    they are loaded without meshes (:func:`~snac_gym.physics.bullet.without_meshes`), as nothing here is
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

    def __init__(
        self, kinematics: Kinematics, dt: float, n_substeps: int, count: int, world_size: int = WORLD_SIZE
    ) -> None:
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


class PyBulletScene:
    """The rendered world of one env: floor, colours, markers and the camera.

    Args:
        client: The PyBullet client of the env's arm.
        body: The arm's body id.
        kinematics: The shared kinematics (base frame ↔ world frame).
        space: The sample cuboid the camera must show.
        width, height: Image size, pixels.
    """

    def __init__(
        self,
        client: int,
        body: int,
        kinematics: Kinematics,
        space: SampleSpace,
        width: int,
        height: int,
        camera: CameraOptions | None = None,
    ) -> None:
        self.client, self.body, self.kinematics = client, body, kinematics
        self.width, self.height = width, height
        self.camera_options = camera
        self._colour_arm()
        self._add_floor()
        self._add_cuboid_edges(space)
        self.target = self._sphere(TARGET_RADIUS, TARGET_COLOUR)
        self.path = [self._sphere(PATH_RADIUS, PATH_COLOUR, PARKED) for _ in range(PATH_POINTS)]
        self.view, self.projection = self._camera(space)

    # -- building ------------------------------------------------------------------------------
    def _colour_arm(self) -> None:
        for link in range(-1, p.getNumJoints(self.body, physicsClientId=self.client)):
            colour = LINK_COLOURS[(link + 1) % len(LINK_COLOURS)]
            p.changeVisualShape(self.body, link, rgbaColor=colour, physicsClientId=self.client)

    def _add_floor(self) -> None:
        shape = p.createVisualShape(
            p.GEOM_BOX, halfExtents=list(FLOOR_HALF_EXTENTS), rgbaColor=FLOOR_COLOUR, physicsClientId=self.client
        )
        p.createMultiBody(
            baseMass=0.0,
            baseVisualShapeIndex=shape,
            basePosition=[0, 0, -FLOOR_HALF_EXTENTS[2]],
            physicsClientId=self.client,
        )

    def _add_cuboid_edges(self, space: SampleSpace) -> None:
        orientation = list(p.getQuaternionFromEuler([0.0, 0.0, base_yaw(self.kinematics)]))
        for corner, extents in cuboid_edges(space):
            shape = p.createVisualShape(
                p.GEOM_BOX, halfExtents=extents.tolist(), rgbaColor=CUBOID_COLOUR, physicsClientId=self.client
            )
            p.createMultiBody(
                baseMass=0.0,
                baseVisualShapeIndex=shape,
                basePosition=self.kinematics.base_to_world(corner).tolist(),
                baseOrientation=orientation,
                physicsClientId=self.client,
            )

    def _sphere(self, radius: float, colour: tuple[float, ...], position: tuple[float, ...] = PARKED) -> int:
        shape = p.createVisualShape(p.GEOM_SPHERE, radius=radius, rgbaColor=colour, physicsClientId=self.client)
        return p.createMultiBody(
            baseMass=0.0, baseVisualShapeIndex=shape, basePosition=list(position), physicsClientId=self.client
        )

    def framed_points(self, space: SampleSpace) -> np.ndarray:
        """World points the camera must show: the cuboid's corners, the base, and the link origins at the
        robot's nominal (elbow-up) pose, how the arm stands while it works in the cuboid."""
        corners = framing_corners(space)
        links = self._links_at([nominal_configuration(self.kinematics)])
        return np.vstack([[self.kinematics.base_to_world(c) for c in corners], [[0.0, 0.0, 0.0]], links])

    def start_points(self, space: SampleSpace) -> np.ndarray:
        """The link origins at start poses as ``reset`` draws them (:func:`framing_configurations`), for
        :func:`fit_camera`'s ``also``."""
        return self._links_at(framing_configurations(self.kinematics, space))

    def _links_at(self, poses: list[np.ndarray]) -> np.ndarray:
        """The link origins of the arm at each of ``poses``, stacked; the arm is put back where it was."""
        joints = [
            i
            for i in range(p.getNumJoints(self.body, physicsClientId=self.client))
            if p.getJointInfo(self.body, i, physicsClientId=self.client)[2] != p.JOINT_FIXED
        ]
        load_pose = [p.getJointState(self.body, i, physicsClientId=self.client)[0] for i in joints]
        links = []
        for pose in poses:
            self._pose(joints, pose)
            links.append(self.link_origins())
        self._pose(joints, load_pose)  # put the arm back where the saved initial state has it
        return np.vstack(links)

    def _pose(self, joints: list[int], angles: Any) -> None:
        for joint, angle in zip(joints, angles):
            p.resetJointState(self.body, joint, float(angle), 0.0, physicsClientId=self.client)

    def link_origins(self) -> np.ndarray:
        """World positions of every link frame of the arm."""
        count = p.getNumJoints(self.body, physicsClientId=self.client)
        states = [
            p.getLinkState(self.body, i, computeForwardKinematics=True, physicsClientId=self.client)
            for i in range(count)
        ]
        return np.array([state[4] for state in states])

    def _camera(self, space: SampleSpace) -> tuple[list[float], list[float]]:
        """View and projection matrices that fit :meth:`framed_points` in the image (:func:`fit_camera`)."""
        camera = fit_camera(
            self.framed_points(space),
            self.kinematics,
            self.width,
            self.height,
            self.camera_options,
            self.start_points(space),
        )
        return camera.view, camera.projection

    # -- per episode and per frame ---------------------------------------------------------------
    def show_reference(self, reference: Reference) -> None:
        """Draw the episode's reference path (the ellipse; nothing for a fixed target)."""
        for marker, position in zip(self.path, path_positions(reference, self.kinematics, len(self.path)), strict=True):
            p.resetBasePositionAndOrientation(marker, list(position), [0, 0, 0, 1], physicsClientId=self.client)

    def image(self, reference_point: np.ndarray) -> np.ndarray:
        """An RGB image ``(height, width, 3)`` with the target marker at ``reference_point`` (base frame)."""
        p.resetBasePositionAndOrientation(
            self.target, list(self.kinematics.base_to_world(reference_point)), [0, 0, 0, 1], physicsClientId=self.client
        )
        _, _, rgba, _, _ = p.getCameraImage(
            self.width,
            self.height,
            viewMatrix=self.view,
            projectionMatrix=self.projection,
            renderer=p.ER_TINY_RENDERER,
            lightDirection=[1.0, -1.0, 2.0],
            shadow=0,
            physicsClientId=self.client,
        )
        return np.asarray(rgba, dtype=np.uint8).reshape(self.height, self.width, 4)[:, :, :3].copy()
