"""Goal-conditioned variants of the task envs, for HER and goal-conditioned RL (Gymnasium-Robotics style).

``gym.make("snac_gym/UR10ReachGoal-v0")`` (and ``UR10EllipseTrackGoal-v0``, ``PandaReachGoal-v0``:
one per robot and task, registered with the task envs by :func:`snac_gym.envs.register_envs`)
wraps the task env and returns ``Dict`` observations:

================  ============================================================  =====
key               value                                                         unit
================  ============================================================  =====
``observation``   θ, θ̇ (2m values); tracking adds ẋ_d(t) (3 values)             rad, rad/s, m/s
``achieved_goal`` the end-effector position x = f(θ), base frame                 m
``desired_goal``  the reference point x_d(t) (fixed for reach, moving for track)  m
================  ============================================================  =====

``observation`` holds nothing that depends on the goal's position, so HER can relabel
``desired_goal`` and the stored transitions stay consistent. For tracking, ẋ_d stays the
original episode's under relabelling: a relabelled goal is a point the reference never
held, moving with the original reference's velocity (HER's usual approximation for moving
goals; document it in any result).

Rewards come from :meth:`GoalTaskEnv.compute_reward`, vectorised over a batch of goals:
``reward_type="sparse"`` (default, as in Gymnasium-Robotics): 0 when
‖achieved − desired‖ ≤ the task's success tolerance, −1 otherwise; ``"dense"``: −‖achieved − desired‖ (m).
``info["is_success"]`` uses the same rule. ``compute_terminated`` is true on success only for
reach with ``terminate_on_success=True``; ``compute_truncated`` is always false (the
registration's ``TimeLimit`` truncates).
"""

from __future__ import annotations

from typing import Any, cast

import gymnasium as gym
import numpy as np

from snac_gym.common.validation import boolean, real_array
from snac_gym.envs.ids import IdRobotCheck
from snac_gym.envs.task_envs import task_env_class
from snac_gym.model.kinematics import Kinematics, damped_least_squares
from snac_gym.model.robots import get_robot
from snac_gym.sampling import SampleSpace, nominal_configuration
from snac_gym.tasks import Task, get_task

#: Reward types of the goal envs.
GOAL_REWARD_TYPES = ("sparse", "dense")
#: Where a goal env's episodes start: ``"sampled"`` (a random seed pose, as the task envs) or
#: ``"nominal"`` (the robot's nominal configuration every time, as panda-gym's neutral pose).
GOAL_STARTS = ("sampled", "nominal")

#: What a goal env's action is: ``"joint"`` (the task env's, joint velocities) or ``"cartesian"``
#: (an end-effector velocity, mapped to joint velocities by the model's damped pseudo-inverse).
GOAL_ACTIONS = ("joint", "cartesian")
#: The Cartesian action's speed at ``|a| = 1`` (m/s): panda-gym's 5 cm per 40 ms step.
CARTESIAN_SPEED = 1.25
#: λ of the Cartesian action's damped pseudo-inverse (m), as the ``dls`` controller's.
CARTESIAN_DAMPING = 0.01

#: The coarse reach preset (``snac_gym/<Robot>ReachGoalCoarse-v0``), sized as panda-gym's PandaReach:
#: 5 cm success tolerance, 50 steps of 40 ms (25 Hz, 2 s), goals in a 30 cm cube centred on the
#: end effector at the nominal configuration, every episode from that configuration, actions
#: normalised to the velocity limits. panda-gym moves the end effector by Cartesian increments;
#: here the action is still the joints' velocity.
COARSE_REACH = {"tolerance": 0.05, "episode_steps": 50, "dt": 0.04, "n_substeps": 10, "box": 0.30}


def coarse_reach_id(robot: str, action: str = "joint", version: int = 0) -> str:
    """The coarse reach preset's id on ``robot``: ``snac_gym/PandaReachGoalCoarse-v0``, or with
    Cartesian actions ``snac_gym/PandaReachGoalCoarseCartesian-v0`` (``version=1``: the -v1 id)."""
    suffix = "Cartesian" if action == "cartesian" else ""
    return f"snac_gym/{get_robot(robot).env_prefix}ReachGoalCoarse{suffix}-v{version}"


def goal_env_id(task: Task[Any], robot: str = "ur10") -> str:
    """The goal variant's id of ``task`` on ``robot``: ``snac_gym/UR10ReachGoal-v0``."""
    return task.env_id_for(robot, goal=True)


class GoalTaskEnv(IdRobotCheck, gym.Env):
    """A task env with a ``Dict`` observation and a goal-conditioned reward (see the module docs).

    Args:
        task: The task's name.
        reward_type: ``"sparse"`` or ``"dense"``.
        success_tolerance: Distance (m) under which the goal counts as reached (default: the task's).
        terminate_on_success: Reach only: end the episode once the goal is reached.
        start: ``"sampled"`` or ``"nominal"`` (:data:`GOAL_STARTS`).
        action: ``"joint"`` (the task env's action) or ``"cartesian"``: a ∈ [−1, 1]ⁿ is the
            end-effector velocity ``cartesian_speed · a`` (m/s), sent as the joint velocities
            ``Jᵀ(JJᵀ + λ²I)⁻¹ v`` (λ = 1 cm, the model's J at the current θ) clipped to the limits,
            as panda-gym's end-effector control moves the tool by Cartesian increments.
        cartesian_speed: The Cartesian action's speed at ``|a| = 1``, m/s.
        finite_observation_bounds: The task env's (``True``: θ̇ unbounded, the -v0 ids; ``"clip"``: every
            field bounded, θ̇ by the velocity limits, and the observation clipped into the bounds, the -v1 ids).
        **env_kwargs: Arguments of the task env (``robot``, ``dt``, ``physics``, ``pybullet_solver`` (the -v1 ids:
            ``"dantzig"``), ``action_type``, ``max_steps``, ...), except ``reward_type``, ``terminate_on_success``
            and ``observation_dtype``.

    Raises:
        ValueError: On an unknown reward type or a task env argument this env sets itself.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 25}
    observation_space: gym.spaces.Dict
    action_space: gym.spaces.Box

    def __init__(
        self,
        task: str,
        reward_type: str = "sparse",
        success_tolerance: float | None = None,
        terminate_on_success: bool = False,
        render_mode: str | None = None,
        start: str = "sampled",
        action: str = "joint",
        cartesian_speed: float = CARTESIAN_SPEED,
        finite_observation_bounds: bool | str = True,
        **env_kwargs: Any,
    ) -> None:
        arguments = {name: value for name, value in locals().items() if name != "self" and not name.startswith("__")}
        if reward_type not in GOAL_REWARD_TYPES:
            raise ValueError(f"reward_type must be one of {GOAL_REWARD_TYPES}, got {reward_type!r}")
        if start not in GOAL_STARTS:
            raise ValueError(f"start must be one of {GOAL_STARTS}, got {start!r}")
        if action not in GOAL_ACTIONS:
            raise ValueError(f"action must be one of {GOAL_ACTIONS}, got {action!r}")
        if not (np.isfinite(cartesian_speed) and cartesian_speed > 0):
            raise ValueError(f"cartesian_speed must be a positive number (m/s), got {cartesian_speed!r}")
        boolean("terminate_on_success", terminate_on_success)
        reserved = {"reward_type", "terminate_on_success", "observation_dtype"} & set(env_kwargs)
        if reserved:
            raise ValueError(f"the goal env sets {sorted(reserved)} itself")
        # every argument as given, read from the call itself (pickling rebuilds the env from them)
        self._init_kwargs = {name: value for name, value in arguments.items() if name != "env_kwargs"}
        self._init_kwargs.update(env_kwargs)
        self.task = get_task(task)
        self.env = task_env_class(self.task)(
            task=self.task,
            success_tolerance=success_tolerance,
            render_mode=render_mode,
            observation_dtype=np.float32,
            finite_observation_bounds=finite_observation_bounds,
            **env_kwargs,
        )
        self.reward_type = reward_type
        self.start = start
        self._start_q = nominal_configuration(self.env.kinematics) if start == "nominal" else None
        self.terminate_on_success = bool(terminate_on_success) and not self.task.moving_reference
        self.success_tolerance = self.env.success_tolerance
        self.render_mode = render_mode
        self.action = action
        self.cartesian_speed = float(cartesian_speed)
        if action == "cartesian":
            self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(self.env.kinematics.task_dim,), dtype=np.float32)
        else:
            self.action_space = self.env.action_space
        self._damping_matrix = CARTESIAN_DAMPING**2 * np.eye(self.env.kinematics.task_dim)
        self.observation_space = self._spaces()

    # -- spaces --------------------------------------------------------------------------------
    def _observation_fields(self) -> list[str]:
        return ["q", "qdot", "xdot_d"] if self.task.moving_reference else ["q", "qdot"]

    def _spaces(self) -> gym.spaces.Dict:
        layout, inner = self.env.obs_layout, self.env.observation_space
        low = np.concatenate([inner.low[layout.slices[name]] for name in self._observation_fields()])
        high = np.concatenate([inner.high[layout.slices[name]] for name in self._observation_fields()])
        goal_low, goal_high = inner.low[layout.slices["x"]], inner.high[layout.slices["x"]]
        return gym.spaces.Dict(
            {
                "observation": gym.spaces.Box(low, high, dtype=np.float32),
                "achieved_goal": gym.spaces.Box(goal_low, goal_high, dtype=np.float32),
                "desired_goal": gym.spaces.Box(goal_low, goal_high, dtype=np.float32),
            }
        )

    def _goal_observation(self, flat: np.ndarray) -> dict[str, np.ndarray]:
        slices = self.env.obs_layout.slices
        return {
            "observation": np.concatenate([flat[slices[name]] for name in self._observation_fields()]),
            "achieved_goal": flat[slices["x"]].copy(),
            "desired_goal": flat[slices["x_d"]].copy(),
        }

    # -- the GoalEnv interface -------------------------------------------------------------------
    def _goal_distance(self, achieved_goal: Any, desired_goal: Any) -> np.ndarray:
        """‖achieved − desired‖ of each pair: both real, finite, of one shape ``(..., goal size)``.

        Raises:
            ValueError: Naming the goal that is not (a NaN goal must not score as reached, nor a goal of another
                size broadcast against the other).
        """
        size = cast(gym.spaces.Box, self.observation_space["desired_goal"]).shape[-1]  # a Box (_spaces)
        achieved = real_array("achieved_goal", achieved_goal)
        desired = real_array("desired_goal", desired_goal)
        for name, goal in (("achieved_goal", achieved), ("desired_goal", desired)):
            if goal.ndim == 0 or goal.shape[-1] != size:
                raise ValueError(f"{name} must have shape (..., {size}), got {goal.shape}")
        if achieved.shape != desired.shape:
            raise ValueError(
                f"achieved_goal and desired_goal must have one shape, got {achieved.shape} and {desired.shape}"
            )
        distance: np.ndarray = np.linalg.norm(achieved - desired, axis=-1)
        return distance

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """Reward of each ``(achieved, desired)`` pair (batched over leading axes); ``info`` is unused.

        Raises:
            ValueError: For goals that are not real, finite and of one shape ``(..., goal size)``.
        """
        distance = self._goal_distance(achieved_goal, desired_goal)
        if self.reward_type == "sparse":
            return -(distance > self.success_tolerance).astype(np.float32)
        return -distance.astype(np.float32)

    def compute_terminated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """True where the goal is reached, for reach with ``terminate_on_success``; false otherwise.

        Raises:
            ValueError: As :meth:`compute_reward`.
        """
        distance = self._goal_distance(achieved_goal, desired_goal)
        return np.logical_and(self.terminate_on_success, distance <= self.success_tolerance)

    def compute_truncated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        """Always false: the registration's ``TimeLimit`` truncates.

        Raises:
            ValueError: As :meth:`compute_reward` (a goal it would refuse is refused here too).
        """
        return np.zeros(self._goal_distance(achieved_goal, desired_goal).shape, dtype=bool)

    # -- episode ---------------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        if self._start_q is not None and not (options and "q0" in options):
            if not (options and self.task.option_key in options):  # a random goal, as without the preset start
                reference = self.task.sample(self.env.kinematics, self.np_random, self.env.sample_space)
                options = {**(options or {}), self.task.option_key: reference}
            options = {**options, "q0": self._start_q}
        flat, info = self.env.reset(seed=seed, options=options)
        return self._goal_observation(flat), info

    def joint_command(self, action: np.ndarray) -> np.ndarray:
        """The task env's action for a Cartesian ``action`` at the current θ (see ``action``)."""
        a = np.asarray(action, dtype=np.float64)
        if a.shape != self.action_space.shape or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be {self.action_space.shape[0]} finite values, got {action!r}")
        # θ at full precision (the observation is float32): the task env's own last observation.
        q = cast(np.ndarray, self.env._obs)[self.env.obs_layout.slices["q"]]  # within an episode (step() checks)
        velocity = self.cartesian_speed * np.clip(a, -1.0, 1.0)
        limits = self.env.velocity_limits
        u = np.clip(
            damped_least_squares(self.env.kinematics.jacobian(q), velocity, self._damping_matrix), -limits, limits
        )
        command: np.ndarray = u / limits if self.env.action_type == "normalized" else u
        return command

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if self.action == "cartesian":
            if self.env._obs is None:  # closed, or not reset: the task env says which
                self.env._no_episode()
            action = self.joint_command(action)
        flat, _, _, truncated, info = self.env.step(action)
        obs = self._goal_observation(flat)
        reward = float(self.compute_reward(obs["achieved_goal"], obs["desired_goal"], info))
        terminated = bool(self.compute_terminated(obs["achieved_goal"], obs["desired_goal"], info))
        # The success flag from the same float32 goals as the reward, so the two never disagree.
        distance = float(np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"]))
        info["is_success"] = distance <= self.success_tolerance
        return obs, reward, terminated, truncated, info

    @property
    def requested_max_steps(self) -> int | None:
        """The ``max_steps`` argument (under ``gym.make`` deprecated for ``max_episode_steps``)."""
        return self.env.requested_max_steps

    @property
    def max_steps(self) -> int:
        """Episode length in control steps."""
        return self.env.max_steps

    @property
    def robot(self) -> str:
        """The registered name of the robot the env drives."""
        return self.env.robot

    @property
    def dt(self) -> float:
        """Control period, s."""
        return self.env.dt

    def render(self) -> np.ndarray | None:
        return self.env.render()

    def close(self) -> None:
        self.env.close()

    def __getstate__(self) -> dict[str, Any]:
        return {"kwargs": self._init_kwargs, "env": self.env, "np_random": self._np_random}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(**state["kwargs"])  # type: ignore[misc]
        self.env.close()
        self.env = state["env"]
        self._np_random = state["np_random"]


class CoarseReachGoalEnv(GoalTaskEnv):
    """The coarse reach preset, ``snac_gym/<Robot>ReachGoalCoarse-v0``: a goal reach sized as panda-gym's PandaReach.

    :data:`COARSE_REACH`: success within 5 cm (sparse reward 0 there, −1 elsewhere), 50 steps of
    40 ms (25 Hz, 2 s per episode), goals drawn in a 30 cm cube centred on the end effector at the
    robot's nominal configuration (and reachable, as every sampled target), every episode started
    from that configuration, actions normalised to the velocity limits ([−1, 1]). The observation
    and the rewards are :class:`GoalTaskEnv`'s. panda-gym moves the end effector by Cartesian
    increments; here the action is the joints' velocity, so the policy learns the arm's
    kinematics as well, unless ``action="cartesian"`` (the ``...ReachGoalCoarseCartesian-v0`` ids):
    then the action is an end-effector velocity of up to 1.25 m/s per axis (panda-gym's 5 cm per
    step), mapped to the joints through the model's damped pseudo-inverse.

    Args:
        robot: A registered robot (the id's; another is refused, as for every id).
        **overrides: Any :class:`GoalTaskEnv` argument, replacing the preset's.
    """

    def __init__(self, robot: str = "panda", **overrides: Any) -> None:
        kinematics = Kinematics(robot)
        centre = kinematics.forward(nominal_configuration(kinematics))
        half = COARSE_REACH["box"] / 2
        preset = {
            "task": "reach",
            "robot": robot,
            "success_tolerance": COARSE_REACH["tolerance"],
            "dt": COARSE_REACH["dt"],
            "n_substeps": COARSE_REACH["n_substeps"],
            "action_type": "normalized",
            "start": "nominal",
            "sample_space": SampleSpace(low=tuple(centre - half), high=tuple(centre + half)),
        }
        super().__init__(**{**preset, **overrides})
        self._init_kwargs = {"robot": robot, **overrides}
