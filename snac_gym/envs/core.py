"""The Gymnasium env that joins the PyBullet arm, the shared kinematics and a task."""

from __future__ import annotations

import math
import os
import sys
import warnings
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, cast

import gymnasium as gym
import numpy as np

from snac_gym.common.validation import boolean, real_number, whole_number
from snac_gym.control.cost import CostConvention, step_costs, weight_matrix
from snac_gym.envs.ids import IdRobotCheck
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.robots import get_robot
from snac_gym.observation import ObservationLayout
from snac_gym.physics import PHYSICS, Arm, check_physics, make_arm, scene_of
from snac_gym.physics.base import check_image_size, check_timing
from snac_gym.physics.scene import CameraOptions, default_render_every
from snac_gym.references import MAX_REFERENCE_SPEED, Reference
from snac_gym.sampling import REGIONS, SampleSpace, sample_seed_pose
from snac_gym.tasks import Task, get_task

#: Action types: joint velocities in rad/s, or [−1, 1] per joint scaled to the velocity limits.
ACTION_TYPES = ("velocity", "normalized")
#: Reward types (see the env docstrings, "Rewards").
REWARD_TYPES = ("dense", "sparse", "shaped", "cost")
#: Weights of ``reward_type="shaped"``: r = −distance_weight·d + precision_bonus·exp(−(d/precision_scale)²)
#: − action_penalty·‖a‖², the defaults of :class:`snac_gym.ppo.envs.RewardSpec`.
SHAPED_REWARD: Mapping[str, float] = MappingProxyType(
    {"distance_weight": 10.0, "precision_bonus": 1.0, "precision_scale": 0.01, "action_penalty": 0.01}
)
#: How far past its URDF limit the observation bounds allow a joint, rad (the simulator's joint
#: limits are soft constraints: a joint driven into one at full speed overshoots it by ~0.01 rad).
JOINT_LIMIT_MARGIN = 0.1
#: Observation dtypes.
OBSERVATION_DTYPES = (np.dtype(np.float64), np.dtype(np.float32))
#: Values of ``finite_observation_bounds``: ±inf (``False``), the physical bounds with θ̇ unbounded
#: (``True``), or every field bounded and the observation clipped into the bounds (``"clip"``, the -v1 default).
OBSERVATION_BOUNDS = (False, True, "clip")
#: The bound of a joint angle whose URDF gives it no finite limit (a continuous joint), rad.
CONTINUOUS_JOINT_BOUND = 2 * math.pi
#: The defaults of the -v1 ids (:func:`snac_gym.envs.register_envs`): normalized float32 actions,
#: float32 observations with finite bounds on every field. The -v0 ids keep the constructor's defaults.
V1_DEFAULTS: Mapping[str, Any] = MappingProxyType(
    {"action_type": "normalized", "observation_dtype": "float32", "finite_observation_bounds": "clip"}
)


def shaped_reward(
    error_norm: Any,
    action: np.ndarray,
    distance_weight: float = SHAPED_REWARD["distance_weight"],
    precision_bonus: float = SHAPED_REWARD["precision_bonus"],
    precision_scale: float = SHAPED_REWARD["precision_scale"],
    action_penalty: float = SHAPED_REWARD["action_penalty"],
) -> float:
    """The ``reward_type="shaped"`` reward; the PPO training wrapper uses the same function.

    One step, or the rows of a batch (the vector env): ``error_norm`` ``(B,)`` and ``action`` ``(B, m)``.

    Args:
        error_norm: d = ‖e‖ after the step, m.
        action: The applied command normalised to [−1, 1] (u / v_max).
        distance_weight, precision_bonus, precision_scale, action_penalty: The weights
            (default :data:`SHAPED_REWARD`).

    Returns:
        −distance_weight·d + precision_bonus·exp(−(d / precision_scale)²) − action_penalty·‖a‖².
    """
    bonus = precision_bonus * np.exp(-((error_norm / precision_scale) ** 2))
    return -distance_weight * error_norm + bonus - action_penalty * np.einsum("...i,...i->...", action, action)


#: Largest ``success_tolerance``, m: a tolerance above a metre counts most of a UR arm's reach (0.5 m to 1.3 m) as
#: reached, so no success rate would measure anything.
MAX_SUCCESS_TOLERANCE = 1.0


def check_sample_space(value: Any, kinematics: Kinematics) -> SampleSpace:
    """``sample_space`` as a :class:`~snac_gym.sampling.SampleSpace`: one given, ``None`` (the robot's cuboid) or a
    region's name, ``"cuboid"`` (the same) or ``"workspace"`` (:meth:`SampleSpace.workspace`).

    Raises:
        ValueError: Naming ``sample_space`` and the valid names, for anything else.
    """
    if value is None or (isinstance(value, str) and value == "cuboid"):
        return SampleSpace.for_robot(kinematics)
    if isinstance(value, str) and value == "workspace":
        return SampleSpace.workspace(kinematics)
    if not isinstance(value, SampleSpace):
        raise ValueError(
            "sample_space must be a snac_gym.sampling.SampleSpace, None or one of "
            f"{', '.join(map(repr, REGIONS))}, got {value!r}"
        )
    return value


#: Longest episode an env accepts, control steps (about 22 hours at 125 Hz): a bound on what a typo can cost.
MAX_EPISODE_STEPS = 10_000_000


def validate_action(action: Any, velocity_limits: np.ndarray) -> np.ndarray:
    """The joint-velocity command an env applies: checked, then clipped to ``±velocity_limits``.

    Shared by the simulated and the real-robot envs so both treat bad input alike.

    Raises:
        ValueError: If ``action`` is not numeric, has the wrong shape, or holds NaN/inf.
    """
    try:
        raw = np.asarray(action)
        if raw.dtype.kind not in "iuf":  # a complex, bool or string action is refused, not cast
            raise TypeError(raw.dtype)
        u = np.array(raw, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"action must be {len(velocity_limits)} joint velocities in rad/s (real numbers), got {action!r}"
        ) from exc
    if u.shape != velocity_limits.shape:
        raise ValueError(f"action must have shape {velocity_limits.shape} (joint velocities, rad/s), got {u.shape}")
    if not np.isfinite(u).all():
        raise ValueError(f"action contains NaN or inf: {u.tolist()}")
    return np.minimum(np.maximum(u, -velocity_limits), velocity_limits)


class ActionCheck:
    """:func:`validate_action` for one env's limits, its constants set up once (at construction).

    The common action, an exact ``ndarray`` of float64 or float32 of the right shape, is checked by
    one ``isfinite`` count and clipped by two ufuncs into one new float64 array; the same values as
    :func:`validate_action`, which every other input (and every refusal, with its message) goes through.

    Args:
        limits: The velocity limits (rad/s; ones for a normalized action), a read-only float64 array.
    """

    __slots__ = ("limits", "_low", "_shape", "_size")

    def __init__(self, limits: np.ndarray) -> None:
        self.limits = limits
        self._low = -limits
        self._shape = limits.shape
        self._size = limits.size

    def __call__(self, action: Any) -> np.ndarray:
        # float64 or float32 ('d', 'f'; either byte order): np.maximum with the float64 bounds gives what
        # np.array(action, dtype=np.float64) would be before the clip, and a new array the env may keep.
        # Every value finite: counted (count_nonzero is a C call, ndarray.all a Python wrapper at twice the cost).
        if (
            type(action) is np.ndarray
            and action.dtype.char in "df"
            and action.shape == self._shape
            and np.count_nonzero(np.isfinite(action)) == self._size
        ):
            u = np.maximum(action, self._low)
            return np.minimum(u, self.limits, out=u)
        return validate_action(action, self.limits)


def resolve_reference(
    task: Task,
    kinematics: Kinematics,
    rng: np.random.Generator,
    space: SampleSpace,
    options: Mapping[str, Any] | None,
) -> Reference:
    """The episode's reference from ``reset`` options (shared by the simulated and real envs).

    No options: a random reference from ``space``. Options without the task's key: the paper's
    reference. Otherwise the given one, checked to be reachable.

    Raises:
        ValueError: On unknown keys, a malformed or an unreachable reference.
    """
    if options is None:
        return task.sample(kinematics, rng, space)
    if not isinstance(options, Mapping):
        raise ValueError(f"options must be a dict, got {type(options).__name__}")
    unknown = set(options) - {"q0", task.option_key}
    if unknown:
        raise ValueError(f"unknown reset options {sorted(unknown)}; allowed: ['q0', '{task.option_key}']")
    if task.option_key in options:
        return task.parse(options[task.option_key], kinematics)
    return task.paper()


def validate_q0(kinematics: Kinematics, value: Any) -> np.ndarray:
    """``options["q0"]`` as an array, checked against the joint count and limits."""
    q0 = np.array(value, dtype=float)
    if q0.shape != (kinematics.n_joints,) or not np.all(np.isfinite(q0)):
        raise ValueError(f"options['q0'] must be {kinematics.n_joints} finite joint angles, got {value!r}")
    outside = np.flatnonzero((q0 < kinematics.lower_limits) | (q0 > kinematics.upper_limits))
    if outside.size:
        j = int(outside[0])
        raise ValueError(
            f"options['q0'][{j}] = {q0[j]} rad is outside the joint limits "
            f"[{kinematics.lower_limits[j]}, {kinematics.upper_limits[j]}]"
        )
    return q0


def draw_episode(
    task: Task,
    kinematics: Kinematics,
    rng: np.random.Generator,
    space: SampleSpace,
    options: Mapping[str, Any] | None,
) -> tuple[np.ndarray, Reference]:
    """The start pose and the reference of one episode, as ``reset`` draws them.

    The reference is drawn (or read from ``options``) first, then the seed pose, both from
    ``rng``: the single env and the batched vector env (:mod:`snac_gym.envs.vector`) call this
    with each episode's generator, so the same seed gives the same episode in both.

    Raises:
        ValueError: On bad options (see :func:`resolve_reference` and :func:`validate_q0`).
    """
    reference = resolve_reference(task, kinematics, rng, space, options)
    q0 = None if options is None else options.get("q0")
    if q0 is None:
        return sample_seed_pose(kinematics, rng, space), reference
    return validate_q0(kinematics, q0), reference


def physics_argument(physics: str, backend: str | None = None) -> str:
    """The ``physics=`` argument, or the deprecated ``backend=`` one (with a ``DeprecationWarning``).

    Raises:
        ValueError: If it is not one of :data:`~snac_gym.physics.PHYSICS`, or both are given and differ.
    """
    if backend is not None:
        warnings.warn(
            f"backend={backend!r} is deprecated; use physics={backend!r} (the arm's model: one of {PHYSICS})",
            DeprecationWarning,
            stacklevel=3,
        )
        if physics not in (backend, PHYSICS[0]):
            raise ValueError(
                f"give physics= only (backend= is its deprecated name), got physics={physics!r}, backend={backend!r}"
            )
        physics = backend
    return check_physics(physics)


def _cost_reward(reward_type: str, cost: CostConvention | None, Q: Any, R: Any) -> CostConvention | None:
    """The cost convention of ``reward_type="cost"`` (``None`` for the other rewards); its Q and R (Q = q_scale·I,
    R = I) become the env's, so the infos' cost terms and the reward price the same cost.

    Raises:
        ValueError: If ``cost`` is given without ``reward_type="cost"``, is not a ``CostConvention``, or
            comes with ``Q``/``R`` (the convention sets them).
    """
    if reward_type != "cost":
        if cost is not None:
            raise ValueError(f"cost= sets the reward of reward_type='cost', got reward_type={reward_type!r}")
        return None
    convention = CostConvention() if cost is None else cost
    if not isinstance(convention, CostConvention):
        raise ValueError(f"cost must be a snac_gym.control.cost.CostConvention, got {cost!r}")
    if Q is not None or R is not None:
        raise ValueError("reward_type='cost' takes Q and R from cost= (Q = q_scale·I, R = I); do not pass Q or R")
    return convention


def check_observation_bounds(value: Any) -> bool | str:
    """``finite_observation_bounds`` checked: ``False``, ``True`` or ``"clip"`` (:data:`OBSERVATION_BOUNDS`).

    Raises:
        ValueError: For any other value.
    """
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if value == "clip":
        return "clip"
    raise ValueError(f"finite_observation_bounds must be False, True or 'clip', got {value!r}")


def _check_choices(
    reward_type: str, action_type: str, observation_dtype: Any, render_mode: str | None, metadata: Mapping[str, Any]
) -> np.dtype:
    """Check the env's enumerated arguments; returns the observation dtype.

    Raises:
        ValueError: Naming the argument and its allowed values.
    """
    if reward_type not in REWARD_TYPES:
        raise ValueError(f"reward_type must be one of {REWARD_TYPES}, got {reward_type!r}")
    if action_type not in ACTION_TYPES:
        raise ValueError(f"action_type must be one of {ACTION_TYPES}, got {action_type!r}")
    try:
        obs_dtype = np.dtype(observation_dtype)
    except TypeError:
        obs_dtype = None
    if obs_dtype not in OBSERVATION_DTYPES:
        raise ValueError(f"observation_dtype must be np.float64 or np.float32, got {observation_dtype!r}")
    if render_mode is not None and render_mode not in metadata["render_modes"]:
        raise ValueError(f"render_mode must be one of {metadata['render_modes']} or None, got {render_mode!r}")
    return obs_dtype


class TaskEnvCore(gym.Env):
    """What every snac-gym env shares, whatever arm it drives (PyBullet, the kinematic model, a real UR).

    The task, the kinematics, the observation layout and its packing, the episode's start from
    ``reset`` options, the per-step cost terms (eq. 6 and the smoothness term, from
    :func:`snac_gym.control.cost.step_costs`), the info dicts and the success rule. Subclasses add the
    arm: :class:`URTaskEnv` (simulated) and :class:`snac_gym.real.RealUREnv` (a real arm behind
    the safety layer).
    """

    observation_space: gym.spaces.Box
    action_space: gym.spaces.Box

    def _init_task(
        self,
        task: Task | str,
        kinematics: Kinematics,
        dt: float,
        Q: Any,
        R: Any,
        success_tolerance: float | None,
        sample_space: SampleSpace | None,
    ) -> None:
        """Set the shared state; raises ``ValueError`` on a bad tolerance or weight matrix."""
        self.task: Task = get_task(task)
        self.task_name = self.task.name
        tolerance = self.task.success_tolerance if success_tolerance is None else success_tolerance
        #: Distance (m) under which the target counts as reached: in (0, :data:`MAX_SUCCESS_TOLERANCE`].
        self.success_tolerance = real_number(
            "success_tolerance (m)", tolerance, 0.0, MAX_SUCCESS_TOLERANCE, low_open=True
        )
        self.kinematics = kinematics
        # A pose task's error is a logarithm (PoseKinematics.task_error), not x − x_d (None).
        self._task_error = getattr(kinematics, "task_error", None)
        self.dt = float(dt)
        m, n = kinematics.n_joints, kinematics.task_dim
        self.Q = weight_matrix(Q, n, "Q")
        self.R = weight_matrix(R, m, "R")
        self.sample_space = check_sample_space(sample_space, kinematics)
        self.velocity_limits = kinematics.velocity_limits.copy()
        self.obs_layout = ObservationLayout(m, n)
        self._error_slice = self.obs_layout.slices["e"]
        self.reference: Reference = self.task.paper()
        self.steps = 0
        self._last_command = np.zeros(m)
        self._obs: np.ndarray | None = None

    @property
    def time(self) -> float:
        """Time since reset, s."""
        return self.steps * self.dt

    def _pack(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        """The observation of the measured state, with the reference at the current time."""
        x_d, xdot_d = self.reference.position_and_velocity(self.time)
        x = self.kinematics.forward(q)
        error = None if self._task_error is None else self._task_error(x, x_d)
        return self.obs_layout.pack(q, qdot, x, x_d, xdot_d, self.reference.centre, error)

    def _is_success(self, error: np.ndarray, squared: float | None = None) -> bool:
        """‖e‖ within the tolerance (``squared``: ‖e‖², where the caller has it already)."""
        return bool((error.dot(error) if squared is None else squared) <= self.success_tolerance**2)

    def _step_costs(self, command: np.ndarray) -> tuple[float, float, float]:
        """``(eₖᵀQeₖ, uₖᵀRuₖ, u̇ₖᵀRu̇ₖ)`` of the step about to apply ``command`` (eₖ: the error now)."""
        assert self._obs is not None  # within an episode
        # one env's 1-D error and command: floats
        return cast(
            "tuple[float, float, float]",
            step_costs(self._obs[self._error_slice], command, self._last_command, self.dt, self.Q, self.R),
        )

    def _reset_info(self, q0: np.ndarray | None) -> dict[str, Any]:
        assert self._obs is not None  # reset() has observed
        error = self._obs[self._error_slice]
        info = {
            "error": error.copy(),
            "error_norm": float(np.linalg.norm(error)),
            "t": 0.0,
            "is_success": self._is_success(error),
            "reference": self.reference.to_dict(),
        }
        if q0 is not None:
            info["q0"] = np.array(q0, dtype=float)
        return info

    def _step_info(self, costs: tuple[float, float, float], command: np.ndarray) -> dict[str, Any]:
        assert self._obs is not None  # within an episode
        error = self._obs[self._error_slice]
        squared = error.dot(error)  # ‖e‖² once, for the norm and the success rule (:meth:`_is_success`)
        return {
            "error": error.copy(),
            "error_norm": math.sqrt(squared),
            "cost_error": costs[0],
            "cost_effort": costs[1],
            "cost_smoothness": costs[2],
            "command": command.copy(),
            "t": self.time,
            "is_success": self._is_success(error, squared),
        }


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
    task_spec: Task | None = None

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
        task: Task | str | None = None,
        backend: str | None = None,
        cost: CostConvention | None = None,
    ) -> None:
        arguments = {name: value for name, value in locals().items() if name != "self" and not name.startswith("__")}
        task = self._resolve_task(task)
        physics = physics_argument(physics, backend)
        dt, n_substeps = check_timing(dt, n_substeps)  # every engine, the kinematic one too
        if max_steps is not None:
            max_steps = whole_number("max_steps", max_steps, 1, MAX_EPISODE_STEPS)
        self.cost_convention = _cost_reward(reward_type, cost, Q, R)
        # What pickling rebuilds the env from: every argument as given, read from the call itself so that a new
        # keyword cannot be left out; the engine and the task as resolved (``backend`` is ``physics``'s old name).
        self._init_kwargs = {
            **{name: value for name, value in arguments.items() if name != "backend"},
            "physics": physics,
            "task": None if self.task_spec is not None else task.name,
        }
        obs_dtype = _check_choices(reward_type, action_type, observation_dtype, render_mode, self.metadata)
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
        self._build_arm(physics, n_substeps, render_every)
        # The action's checks, set up once: the velocity limits are a constant of the env (read-only).
        self.velocity_limits.setflags(write=False)
        self._unit_limits = np.ones(self.kinematics.n_joints)  # the bounds of a normalized action
        self._unit_limits.setflags(write=False)
        self._check_velocity = ActionCheck(self.velocity_limits)
        self._check_normalized = ActionCheck(self._unit_limits)
        self._build_spaces(finite_observation_bounds)

    def _resolve_task(self, task: Task | str | None) -> Task:
        """The class's task, or ``task=`` for :class:`URTaskEnv` itself."""
        own = type(self).task_spec
        if task is None:
            if own is None:
                raise TypeError(f"{type(self).__name__} needs task=<a registered task's name>")
            return own
        task = cast(Task, get_task(task))  # a registered task (get_task returns Any)
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
        # Without a render mode nothing draws the arm: its meshes (0.3 s of every env's construction) are not loaded.
        meshes = self.render_mode is not None
        self.arm: Arm = make_arm(physics, self.kinematics, self.dt, n_substeps, gui=gui, meshes=meshes)
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
            assert self.cost_convention is not None  # set for reward_type="cost" (_cost_reward)
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
