"""Gymnasium environments: a PyBullet UR arm under joint-velocity control, and its batched kinematic vector env."""

import warnings
from typing import Any, cast

import gymnasium as gym

from snac_gym.envs.core import (
    ACTION_TYPES,
    OBSERVATION_BOUNDS,
    REWARD_TYPES,
    SHAPED_REWARD,
    V1_DEFAULTS,
    URTaskEnv,
    shaped_reward,
)
from snac_gym.envs.goal import COARSE_REACH, coarse_reach_id
from snac_gym.envs.ids import REGISTERED_IDS, RegisteredId
from snac_gym.envs.task_envs import (
    TASK_ENV_CLASSES,
    EllipseTrackEnv,
    PoseEllipseTrackEnv,
    PoseReachEnv,
    ReachEnv,
    UR10EllipseTrackEnv,
    UR10ReachEnv,
    task_env_class,
)
from snac_gym.envs.vector import task_vector_env_class, vector_env_supports
from snac_gym.model.robots import all_robots
from snac_gym.tasks import Task, all_tasks, get_task
from snac_gym.tasks.pose import register_pose_tasks

#: The registered -v0 task env ids (one per robot and task) and their entry points (filled by :func:`register_envs`).
ENV_IDS: dict[str, str] = {}
#: The registered -v0 goal-conditioned ids (:mod:`snac_gym.envs.goal`) and their entry points.
GOAL_ENV_IDS: dict[str, str] = {}
#: The -v1 task env ids (the RL-ready defaults, :data:`~snac_gym.envs.core.V1_DEFAULTS`) and their entry points.
ENV_IDS_V1: dict[str, str] = {}
#: The -v1 goal-conditioned ids and their entry points.
GOAL_ENV_IDS_V1: dict[str, str] = {}
#: What a -v1 goal id sets (the goal env's observation is float32 already).
GOAL_V1_DEFAULTS = {"action_type": "normalized", "finite_observation_bounds": "clip", "pybullet_solver": "dantzig"}
#: The versions every id is registered in: 0 (physical units, float64) and 1 (RL-ready).
VERSIONS = (0, 1)

# gym.make of an id with a newer version warns "The environment ... is out of date. You should consider
# upgrading to version `v1`". A -v0 id is not deprecated: it is the physical-units env (the evaluator, the
# demo, the benchmarks and the real arm use it), so the notice is silenced for snac-gym's -v0 ids only.
#: The message (a regex) of Gymnasium's "out of date" notice for a snac-gym -v0 id, silenced on import.
V0_NOTICE = r".*The environment snac_gym/\w+-v0 is out of date"
warnings.filterwarnings("ignore", message=V0_NOTICE, category=DeprecationWarning)


def register_envs() -> None:
    """Register the ids of every robot of :data:`snac_gym.model.robots.ROBOTS` and task of
    :data:`snac_gym.tasks.TASKS`, each with its goal variant (idempotent).

    ``snac_gym/<Robot><Task>-v0`` (:mod:`snac_gym.envs.ids`) runs the task's env class with
    ``robot=<robot>``; ``snac_gym/<Robot><Task>Goal-v0`` its :class:`~snac_gym.envs.goal.GoalTaskEnv`.
    Each has a ``-v1`` beside it, the same env with the RL-ready defaults (normalized float32
    actions, float32 observations clipped into finite bounds, PyBullet's motors solved directly:
    :data:`~snac_gym.envs.core.V1_DEFAULTS`);
    any of them can still be given to ``gym.make``, which overrides it.
    Each id's episode length is its task's ``episode_steps``, registered as ``max_episode_steps``
    (the ``TimeLimit`` wrapper ``gym.make`` adds; ``gym.make(id, max_episode_steps=N)`` changes
    it). A task or a robot registered later gets its ids from the next call.
    """
    robots = all_robots()
    for task in all_tasks():
        for robot in robots:
            for version in VERSIONS:
                _register(task, robot.name, goal=False, version=version)
                _register(task, robot.name, goal=True, version=version)
    for robot in robots:
        for version in VERSIONS:
            _register_coarse_reach(robot.name, version)


def register_pose_envs() -> None:
    """Register the pose tasks (:func:`snac_gym.tasks.pose.register_pose_tasks`) and their ids (idempotent):
    ``snac_gym/UR10PoseReach-v0``, ``snac_gym/UR10PoseEllipseTrack-v0`` and those of the other robots."""
    register_pose_tasks()
    register_envs()


def _register(task: Task[Any], robot: str, goal: bool, version: int = 0) -> None:
    """Register the id of ``task`` on ``robot`` (its goal variant if ``goal``) in ``version`` unless it exists."""
    env_id = task.env_id_for(robot, goal=goal, version=version)
    env_class = task_env_class(task)
    kwargs = {"robot": robot} if env_class.task_spec is task and not goal else {"robot": robot, "task": task.name}
    if version == 1:
        kwargs.update(GOAL_V1_DEFAULTS if goal else V1_DEFAULTS)
    if goal:
        entry_point, vector_entry_point = "snac_gym.envs.goal:GoalTaskEnv", None
    else:
        entry_point = f"{env_class.__module__}:{env_class.__qualname__}"
        # The batched env steps end-effector positions only: a task with its own coordinates (a
        # pose task's PoseKinematics) gets no vector entry point, and make_vec falls back to sync.
        vector_class = task_vector_env_class(task) if vector_env_supports(task) else None
        vector_entry_point = None if vector_class is None else f"{vector_class.__module__}:{vector_class.__qualname__}"
    tables = (GOAL_ENV_IDS, ENV_IDS) if version == 0 else (GOAL_ENV_IDS_V1, ENV_IDS_V1)
    tables[0 if goal else 1][env_id] = entry_point
    REGISTERED_IDS[env_id] = RegisteredId(robot, task.name, goal, version)
    if env_id in gym.registry:
        return
    gym.register(
        id=env_id,
        entry_point=entry_point,
        kwargs=kwargs,
        disable_env_checker=False,
        max_episode_steps=task.episode_steps,
        vector_entry_point=vector_entry_point,
    )


def _register_coarse_reach(robot: str, version: int = 0) -> None:
    """Register the coarse reach preset on ``robot`` (:data:`snac_gym.envs.goal.COARSE_REACH`) in ``version``
    unless it exists (its actions are normalized in both; -v1 bounds θ̇, clips the observation, solves PyBullet's
    motors directly and, as panda-gym's PandaReach, ends the episode on success)."""
    table = GOAL_ENV_IDS if version == 0 else GOAL_ENV_IDS_V1
    for action in ("joint", "cartesian"):
        env_id = coarse_reach_id(robot, action, version)
        if env_id in gym.registry:
            continue
        table[env_id] = "snac_gym.envs.goal:CoarseReachGoalEnv"
        REGISTERED_IDS[env_id] = RegisteredId(robot, "reach", True, version)
        kwargs: dict[str, Any] = {"robot": robot} if action == "joint" else {"robot": robot, "action": action}
        if version == 1:
            kwargs.update(finite_observation_bounds="clip", terminate_on_success=True, pybullet_solver="dantzig")
        gym.register(
            id=env_id,
            entry_point=table[env_id],
            kwargs=kwargs,
            disable_env_checker=False,
            max_episode_steps=cast(int, COARSE_REACH["episode_steps"]),  # an int in the dict of floats
        )


def make_task_env(task: Task[Any] | str, robot: str = "ur10", version: int = 0, **kwargs: Any) -> Any:
    """``gym.make`` of ``task``'s id on ``robot`` (registering the ids of a robot or task added since).

    Args:
        task: A registered task (or its name).
        robot: A registered robot.
        version: The id's version: 0 (physical units, the default) or 1 (the RL-ready defaults).
        **kwargs: Arguments of ``gym.make`` and the env (not ``robot``: the id fixes it);
            ``max_steps=N`` is passed on as ``max_episode_steps=N``.
    """
    env_id = get_task(task).env_id_for(robot, version=version)
    if env_id not in gym.registry:
        register_envs()
    if "max_steps" in kwargs:  # the episode length is Gymnasium's TimeLimit, max_episode_steps
        kwargs["max_episode_steps"] = kwargs.pop("max_steps")
    return gym.make(env_id, **kwargs)


def unregister_envs(task: str | None = None, robot: str | None = None) -> list[str]:
    """Remove the ids of a task or of a robot (both: that pair) from Gymnasium and the tables here.

    The inverse of :func:`register_envs` for a task or robot taken out of its registry again.

    Returns:
        The ids removed.
    """
    removed = [
        env_id
        for env_id, entry in REGISTERED_IDS.items()
        if (task is None or entry.task == task) and (robot is None or entry.robot == robot)
    ]
    for env_id in removed:
        gym.registry.pop(env_id, None)
        for table in (ENV_IDS, GOAL_ENV_IDS, ENV_IDS_V1, GOAL_ENV_IDS_V1):
            table.pop(env_id, None)
        REGISTERED_IDS.pop(env_id, None)
    return removed


__all__ = [
    "ACTION_TYPES",
    "ENV_IDS",
    "ENV_IDS_V1",
    "GOAL_ENV_IDS_V1",
    "OBSERVATION_BOUNDS",
    "V0_NOTICE",
    "V1_DEFAULTS",
    "VERSIONS",
    "register_pose_envs",
    "GOAL_ENV_IDS",
    "REGISTERED_IDS",
    "REWARD_TYPES",
    "SHAPED_REWARD",
    "TASK_ENV_CLASSES",
    "EllipseTrackEnv",
    "PoseEllipseTrackEnv",
    "PoseReachEnv",
    "ReachEnv",
    "UR10EllipseTrackEnv",
    "UR10ReachEnv",
    "URTaskEnv",
    "register_envs",
    "shaped_reward",
    "make_task_env",
    "task_env_class",
    "unregister_envs",
]
