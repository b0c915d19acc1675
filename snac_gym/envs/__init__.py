"""Gymnasium environments: a PyBullet UR arm under joint-velocity control."""

from snac_gym.envs.core import (
    ACTION_TYPES,
    REWARD_TYPES,
    SHAPED_REWARD,
    UR10EllipseTrackEnv,
    UR10ReachEnv,
    URTaskEnv,
    shaped_reward,
    task_env_class,
)
from snac_gym.tasks import TASKS

#: Registered ids and their entry points, one per registered task (filled by :func:`register_envs`).
ENV_IDS: dict[str, str] = {}


def register_envs() -> None:
    """Register the env of every task of :data:`snac_gym.tasks.TASKS` with Gymnasium (idempotent).

    Each id's episode length is its task's ``episode_steps``, registered as
    ``max_episode_steps`` (the ``TimeLimit`` wrapper ``gym.make`` adds); the registered
    :func:`~snac_gym.envs.core.apply_episode_length` hook lets the ``max_steps`` argument set it.
    A task registered later gets its id from the next call.
    """
    import gymnasium as gym
    from gymnasium.envs.registration import WrapperSpec

    hook = WrapperSpec(name="EpisodeLength", entry_point="snac_gym.envs.core:apply_episode_length", kwargs={})
    for task in TASKS.values():
        env_class = task_env_class(task)
        ENV_IDS[task.env_id] = f"{env_class.__module__}:{env_class.__qualname__}"
        if task.env_id not in gym.registry:
            gym.register(
                id=task.env_id, entry_point=ENV_IDS[task.env_id], disable_env_checker=False,
                max_episode_steps=env_class.default_max_steps, additional_wrappers=(hook,),
            )


__all__ = [
    "ACTION_TYPES",
    "ENV_IDS",
    "REWARD_TYPES",
    "SHAPED_REWARD",
    "UR10EllipseTrackEnv",
    "UR10ReachEnv",
    "URTaskEnv",
    "register_envs",
    "shaped_reward",
    "task_env_class",
]
