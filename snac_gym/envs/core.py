"""The Gymnasium env that joins the PyBullet arm, the shared kinematics and a task.

The env's parts live beside it, each re-exported here (the names' old home): :mod:`~snac_gym.envs.arguments` (the
checks of its arguments and ``reset`` options, the episode's draw), :mod:`~snac_gym.envs.rewards` (the shaped and
cost rewards) and :mod:`~snac_gym.envs.task_core` (:class:`TaskEnvCore`, what the real-arm env shares).
"""

from __future__ import annotations

import math
import os
import sys
import warnings
from collections.abc import Mapping
from typing import Any, cast

import gymnasium as gym
import numpy as np

from snac_gym.common.validation import boolean, whole_number
from snac_gym.control.cost import CostConvention
from snac_gym.envs.arguments import (
    ACTION_TYPES,
    MAX_EPISODE_STEPS,
    MAX_SUCCESS_TOLERANCE,
    OBSERVATION_BOUNDS,
    OBSERVATION_DTYPES,
    V1_DEFAULTS,
    ActionCheck,
    check_choices,
    check_observation_bounds,
    check_sample_space,
    draw_episode,
    physics_argument,
    resolve_reference,
    validate_action,
    validate_q0,
)
from snac_gym.envs.ids import IdRobotCheck
from snac_gym.envs.rewards import REWARD_TYPES, SHAPED_REWARD, cost_reward_convention, shaped_reward
from snac_gym.envs.task_core import TaskEnvCore
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.robots import get_robot
from snac_gym.physics import Arm, make_arm, scene_of
from snac_gym.physics.base import check_image_size, check_pybullet_solver, check_timing
from snac_gym.physics.scene import CameraOptions, default_render_every
from snac_gym.references import MAX_REFERENCE_SPEED, Reference
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import Task, get_task

__all__ = [
    "ACTION_TYPES",
    "CONTINUOUS_JOINT_BOUND",
    "JOINT_LIMIT_MARGIN",
    "MAX_EPISODE_STEPS",
    "MAX_SUCCESS_TOLERANCE",
    "OBSERVATION_BOUNDS",
    "OBSERVATION_DTYPES",
    "REWARD_TYPES",
    "SHAPED_REWARD",
    "V1_DEFAULTS",
    "ActionCheck",
    "TaskEnvCore",
    "URTaskEnv",
    "check_observation_bounds",
    "check_sample_space",
    "draw_episode",
    "physics_argument",
    "resolve_reference",
    "shaped_reward",
    "validate_action",
    "validate_q0",
]

#: How far past its URDF limit the observation bounds allow a joint, rad (the simulator's joint
#: limits are soft constraints: a joint driven into one at full speed overshoots it by ~0.01 rad).
JOINT_LIMIT_MARGIN = 0.1
#: The bound of a joint angle whose URDF gives it no finite limit (a continuous joint), rad.
CONTINUOUS_JOINT_BOUND = 2 * math.pi


class URTaskEnv(IdRobotCheck, TaskEnvCore):
    """The simulated env: a registered robot in PyBullet or on the kinematic model, running a task.

    Each task of the paper has its own subclass with its full documentation: :class:`ReachEnv`,
    :class:`EllipseTrackEnv` (and the opt-in :class:`PoseReachEnv`, :class:`PoseEllipseTrackEnv`).
    A task registered later (docs/extending.md) runs in this class itself, given ``task=``; its
    ids pass it. The arguments are those of :class:`ReachEnv`, plus:

    Args:
        task: The task's name (or :class:`~snac_gym.tasks.Task`); a subclass fixes it.

    Raises:
        ValueError: On a bad argument, naming it.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 25}
    #: The task of a subclass (``None``: given by ``task=``).
    task_spec: Task[Any] | None = None

    def __init__(
        self,
        robot: str = "ur10",
        dt: float = 1.0 / 125.0,
        n_substeps: int = 3,
        max_steps: int | None = None,
        reward_type: str = "dense",
        Q: np.ndarray | None = None,
        R: np.ndarray | None = None,
        success_tolerance: float | None = None,
        terminate_on_success: bool = False,
        sample_space: SampleSpace | None = None,
        render_mode: str | None = None,
        render_width: int = 480,
        render_height: int = 480,
        render_distance: float | None = None,
        render_yaw: float | None = None,
        render_pitch: float | None = None,
        render_target_position: Any = None,
        action_type: str = "velocity",
        observation_dtype: Any = np.float64,
        finite_observation_bounds: bool | str = False,
        physics: str = "pybullet",
        render_every: int | None = None,
        task: Task[Any] | str | None = None,
        backend: str | None = None,
        cost: CostConvention | None = None,
        pybullet_solver: str = "pgs",
    ) -> None:
        arguments = {name: value for name, value in locals().items() if name != "self" and not name.startswith("__")}
        task = self._resolve_task(task)
        physics = physics_argument(physics, backend)
        pybullet_solver = check_pybullet_solver(pybullet_solver)  # every engine, so that a typo is not ignored
        dt, n_substeps = check_timing(dt, n_substeps)  # every engine, the kinematic one too
        if max_steps is not None:
            max_steps = whole_number("max_steps", max_steps, 1, MAX_EPISODE_STEPS)
        self.cost_convention = cost_reward_convention(reward_type, cost, Q, R)
        # What pickling rebuilds the env from: every argument as given, read from the call itself so that a new
        # keyword cannot be left out; the engine and the task as resolved (``backend`` is ``physics``'s old name).
        self._init_kwargs = {
            **{name: value for name, value in arguments.items() if name != "backend"},
            "physics": physics,
            "task": None if self.task_spec is not None else task.name,
        }
        obs_dtype = check_choices(reward_type, action_type, observation_dtype, render_mode, self.metadata)
        finite_observation_bounds = check_observation_bounds(finite_observation_bounds)
        if physics == "kinematic" and render_mode is not None:
            raise ValueError(
                f"render_mode={render_mode!r} needs physics='pybullet' or 'mujoco' (the kinematic arm has no scene)"
            )
        #: Episode length in control steps of the task's ids (their ``max_episode_steps``).
        self.default_max_steps = task.episode_steps
        #: The ``max_steps`` argument: when given, the env truncates itself after it (``None``: the
        #: registration's ``TimeLimit`` does; under ``gym.make`` pass ``max_episode_steps`` instead).
        self.requested_max_steps = None if max_steps is None else int(max_steps)
        #: Episode length in control steps (the default horizon of :func:`snac_gym.rollout.rollout`).
        self.max_steps = self.default_max_steps if max_steps is None else int(max_steps)
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be at least 1, got {max_steps}")
        # a pose task's PoseKinematics stands in for Kinematics (it forwards the rest to its position Kinematics)
        kinematics = cast(Kinematics, task.make_kinematics(robot))
        if self.cost_convention is not None:
            Q = self.cost_convention.error_weight(kinematics.task_dim)
        self._init_task(task, kinematics, dt, Q, R, success_tolerance, sample_space)
        self.reward_type = reward_type
        self.terminate_on_success = boolean("terminate_on_success", terminate_on_success)
        self.render_mode = render_mode
        self.render_width, self.render_height = check_image_size(render_width, render_height)
        self.camera_options = CameraOptions(render_distance, render_yaw, render_pitch, render_target_position)

        self.action_type = action_type
        self.observation_dtype = obs_dtype
        #: The arm's model: ``"pybullet"``, ``"kinematic"`` or ``"mujoco"`` (:data:`~snac_gym.physics.PHYSICS`).
        self.physics = physics
        #: How the PyBullet arm's motors are solved (:data:`~snac_gym.physics.base.PYBULLET_SOLVERS`; -v0 ``"pgs"``,
        #: -v1 ``"dantzig"``); read by the PyBullet engine only.
        self.pybullet_solver = pybullet_solver
        self._build_arm(physics, n_substeps, render_every)
        # The action's checks, set up once: the velocity limits are a constant of the env (read-only).
        self.velocity_limits.setflags(write=False)
        self._unit_limits = np.ones(self.kinematics.n_joints)  # the bounds of a normalized action
        self._unit_limits.setflags(write=False)
        self._check_velocity = ActionCheck(self.velocity_limits)
        self._check_normalized = ActionCheck(self._unit_limits)
        self._build_spaces(finite_observation_bounds)

    def _resolve_task(self, task: Task[Any] | str | None) -> Task[Any]:
        """The class's task, or ``task=`` for :class:`URTaskEnv` itself."""
        own = type(self).task_spec
        if task is None:
            if own is None:
                raise TypeError(f"{type(self).__name__} needs task=<a registered task's name>")
            return own
        task = cast("Task[Any]", get_task(task))  # a registered task (get_task returns Any)
        if own is not None and task is not own:
            raise ValueError(f"{type(self).__name__} runs the task {own.name!r}, got task={task.name!r}")
        return task

    @property
    def robot(self) -> str:
        """The registered name of the robot this env drives."""
        return get_robot(self.kinematics.robot).name

    @property
    def backend(self) -> str:
        """Deprecated name of :attr:`physics`."""
        warnings.warn("env.backend is deprecated; use env.physics", DeprecationWarning, stacklevel=2)
        return self.physics

    def _build_arm(self, physics: str, n_substeps: int, render_every: int | None) -> None:
        """The arm, and the rendered scene when there is a render mode."""
        # "human" without a display (or in MuJoCo, which renders headless only) shows nothing and warns on
        # the first step (construction, reset and render stay quiet: Gymnasium's checker builds, resets and renders
        # every declared mode).
        no_display = sys.platform.startswith("linux") and not os.environ.get("DISPLAY")
        self._headless_human = self.render_mode == "human" and (no_display or physics == "mujoco")
        gui = self.render_mode == "human" and not self._headless_human
        # Without a render mode, or "human" with no display, nothing draws the arm: its meshes (0.3 s of every env's
        # construction) are not loaded.
        meshes = self.render_mode is not None and not self._headless_human
        self.arm: Arm = make_arm(
            physics, self.kinematics, self.dt, n_substeps, gui=gui, meshes=meshes, pybullet_solver=self.pybullet_solver
        )
        self.dt = self.arm.dt
        #: The PyBullet world (renders; ``None`` for the kinematic and MuJoCo arms).
        self.sim = getattr(self.arm, "sim", None)
        self._warned_headless = False
        # A recorded video plays in real time: one frame per control step, a new image every render_every.
        self.metadata = {**type(self).metadata, "render_fps": round(1.0 / self.dt)}
        self.render_every = default_render_every(self.dt) if render_every is None else int(render_every)
        if self.render_every < 1:
            raise ValueError(f"render_every must be a positive number of control steps, got {render_every!r}")
        self._scene: Any = None
        if self.render_mode is not None and not self._headless_human:
            # Built before the first reset: PyBullet restores a saved state only into the same bodies.
            self._scene = scene_of(
                self.arm, self.kinematics, self.sample_space, self.render_width, self.render_height, self.camera_options
            )
            cast(Any, self.arm).save_initial_state()  # a drawn arm (PyBullet, MuJoCo): not in the Arm protocol
        self._frame: tuple[int, np.ndarray] | None = None  # (step, image) of the last rendered image
        self._shown_reference: Reference | None = None

    def _build_spaces(self, finite_observation_bounds: bool | str) -> None:
        """The action space of :attr:`action_type` and the observation space (see the class docs)."""
        if self.action_type == "normalized":
            self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(self.kinematics.n_joints,), dtype=np.float32)
        else:
            self.action_space = gym.spaces.Box(-self.velocity_limits, self.velocity_limits, dtype=np.float64)
        #: ``finite_observation_bounds``: ``False``, ``True`` or ``"clip"`` (:data:`OBSERVATION_BOUNDS`).
        self.finite_observation_bounds = finite_observation_bounds
        clip = finite_observation_bounds == "clip"
        low, high = self.observation_bounds(bounded_velocities=clip)
        #: The float64 ``(low, high)`` each observation is clipped into (``finite_observation_bounds="clip"``), else
        #: ``None``.
        self.observation_clip = (low, high) if clip else None
        if not finite_observation_bounds:  # the -v0 default: ±inf, the real-robot env's space
            low, high = np.full_like(low, -np.inf), np.full_like(high, np.inf)
        dtype = self.observation_dtype
        self.observation_space = gym.spaces.Box(low.astype(dtype), high.astype(dtype), dtype=dtype)

    def observation_bounds(self, bounded_velocities: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Float64 ``(low, high)`` of the observation (see "Observation Space").

        θ: the URDF limits widened by :data:`JOINT_LIMIT_MARGIN` (±:data:`CONTINUOUS_JOINT_BOUND` where a
        joint has no finite limit); θ̇: ±inf, or with ``bounded_velocities`` the velocity limits; positions:
        ±ρ per axis, ρ the sum of the arm's link offsets (the furthest the tool can be from the base);
        orientations (a pose task's rotation vectors): ±π; ẋ_d: ±3 m/s; e: ±2ρ (±π for orientation).
        """
        k = self.kinematics
        reach = sum(float(np.linalg.norm(k.model.jointPlacements[j].translation)) for j in range(1, k.model.njoints))
        reach += float(np.linalg.norm(k.ee_mount()[1]))
        n = k.task_dim
        box = np.full(n, reach)
        error = np.full(n, 2 * reach)
        if n == 6:  # a pose task: [p; log₃ R], a rotation vector has norm ≤ π
            box[3:] = error[3:] = math.pi
        speed = np.full(n, MAX_REFERENCE_SPEED)
        qdot = k.velocity_limits.copy() if bounded_velocities else np.full(k.n_joints, np.inf)
        upper = np.where(np.isfinite(k.upper_limits), k.upper_limits + JOINT_LIMIT_MARGIN, CONTINUOUS_JOINT_BOUND)
        lower = np.where(np.isfinite(k.lower_limits), k.lower_limits - JOINT_LIMIT_MARGIN, -CONTINUOUS_JOINT_BOUND)
        high = np.empty(self.obs_layout.size)
        for name, value in (
            ("q", upper),
            ("qdot", qdot),
            ("x", box),
            ("x_d", box),
            ("xdot_d", speed),
            ("e", error),
            ("x_c", box),
        ):
            high[self.obs_layout.slices[name]] = value
        low = -high
        low[self.obs_layout.slices["q"]] = lower
        return low, high

    # -- episode -----------------------------------------------------------------------------
    def _observe(self) -> np.ndarray:
        return self._pack(*self.arm.joint_state())

    def _parse_options(self, options: Mapping[str, Any] | None) -> tuple[np.ndarray, Reference]:
        return draw_episode(self.task, self.kinematics, self.np_random, self.sample_space, options)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        if self._closed:
            self._refuse_closed("reset")
        super().reset(seed=seed)
        q0, reference = self._parse_options(options)
        self.arm.reset(q0)
        self._shown_reference = None  # the restored state parked the path markers
        self.reference = reference
        self.steps = 0
        self._last_command = np.zeros(self.kinematics.n_joints)
        self._obs = self._observe()
        if self.render_mode == "human":
            self.render()
        return self._output(self._obs), self._reset_info(q0)

    def _output(self, obs: np.ndarray) -> np.ndarray:
        """A copy of ``obs`` in the observation dtype, clipped into its bounds with
        ``finite_observation_bounds="clip"``."""
        clip = self.observation_clip
        if clip is None:
            return obs.astype(self.observation_dtype)  # astype copies, also for float64
        # Clipped in float64 (rounding keeps it inside the float32 bounds), into a new array: np.clip's ufunc,
        # without np.clip's dispatch; float64 needs no second copy.
        clipped = obs.clip(clip[0], clip[1])
        return clipped if self.observation_dtype == np.float64 else clipped.astype(self.observation_dtype)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._obs is None:  # not reset yet, or closed (close() drops the observation): no per-step test
            self._no_episode()
        if self.action_type == "normalized":
            u = self._check_normalized(action)
            u *= self.velocity_limits  # u is a new array (ActionCheck)
        else:
            u = self._check_velocity(action)
        costs = self._step_costs(u)
        self.arm.apply(u)
        self.steps += 1
        self._last_command = u
        self._obs = self._observe()
        info = self._step_info(costs, u)
        if self.reward_type == "dense":
            reward: float | np.ndarray = -(costs[0] + costs[1])
        elif self.reward_type == "shaped":
            reward = shaped_reward(info["error_norm"], u / self.velocity_limits)
        elif self.reward_type == "cost":  # minus the step's share of V: the return is −V
            assert self.cost_convention is not None  # set for reward_type="cost" (cost_reward_convention)
            reward = -self.dt * self.cost_convention.step_rate(*costs, first_step=self.steps == 1)
        else:
            reward = 0.0 if info["is_success"] else -1.0
        terminated = self.terminate_on_success and info["is_success"]
        truncated = self.requested_max_steps is not None and self.steps >= self.requested_max_steps
        if self.render_mode == "human":
            if self._headless_human and not self._warned_headless:
                self._warn_headless()  # the first frame of an episode that shows nothing
            self.render()
        return self._output(self._obs), float(reward), terminated, truncated, info

    # -- rendering -----------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """The frame (``"rgb_array"``), or ``None`` after drawing it in the GUI (``"human"``).

        ``"human"`` without a display (or with MuJoCo) shows nothing and returns ``None``; it warns once, on
        the first ``step()``, where a ``"human"`` env draws its frames. Construction, ``reset()`` and
        ``render()`` stay quiet: Gymnasium's ``check_env`` builds, resets and renders a ``"human"`` env of
        every id, headless too.
        """
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        if self._headless_human:
            return None
        if self._shown_reference is not self.reference:
            self._scene.show_reference(self.reference)
            self._shown_reference, self._frame = self.reference, None
        if self.render_mode == "human":
            self._scene.image(self.reference.position(self.time))  # moves the target in the GUI too
            return None
        if self._frame is None or self.steps < self._frame[0] or self.steps - self._frame[0] >= self.render_every:
            self._frame = (self.steps, self._scene.image(self.reference.position(self.time)))
        return self._frame[1].copy()

    def _warn_headless(self) -> None:
        """Say (once) that ``render_mode="human"`` shows nothing here."""
        gym.logger.warn(
            "render_mode='human' with physics='mujoco' shows nothing (MuJoCo renders headless here); use "
            "render_mode='rgb_array' (gymnasium.wrappers.HumanRendering shows those frames in a window)"
            if self.physics == "mujoco"
            else "render_mode='human' opens the PyBullet GUI and needs a display, but DISPLAY is not set: "
            "nothing is shown; use render_mode='rgb_array' to render headless"
        )
        self._warned_headless = True

    #: Whether :meth:`close` was called: the arm's simulator is gone, ``step()`` and ``reset()`` are refused.
    _closed = False

    def _refuse_closed(self, method: str) -> None:
        raise RuntimeError(f"{method}() after close(): the {self.physics} arm is closed; make a new env")

    def _no_episode(self) -> None:
        """Refuse a ``step()`` without an episode: after :meth:`close`, or before the first ``reset()``."""
        if self._closed:
            self._refuse_closed("step")
        raise RuntimeError("call reset() before step()")

    def close(self) -> None:
        self._closed = True
        self._obs = None
        if getattr(self, "_scene", None) is not None and hasattr(self._scene, "close"):
            self._scene.close()  # MuJoCo's scene holds an OpenGL context
        if getattr(self, "arm", None) is not None:
            self.arm.close()

    # -- pickling: rebuild the simulator from the arguments and put the episode back ----------
    def __getstate__(self) -> dict[str, Any]:
        state: dict[str, Any] = {"kwargs": self._init_kwargs, "np_random_state": None, "episode": None}
        if self._np_random is not None:
            state["np_random_state"] = self._np_random.bit_generator.state
        if self._obs is not None:
            q, qdot = self.arm.joint_state()
            state["episode"] = (q, qdot, self.reference, self.steps, self._last_command.copy())
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(**state["kwargs"])  # type: ignore[misc]
        if state["np_random_state"] is not None:
            self._np_random = np.random.Generator(np.random.PCG64())
            self._np_random.bit_generator.state = state["np_random_state"]
        if state["episode"] is not None:
            q, qdot, self.reference, self.steps, self._last_command = state["episode"]
            self.arm.restore(q, qdot, self._last_command)
            self._obs = self._observe()
