"""Gymnasium environments: a PyBullet UR arm under joint-velocity control, and its batched kinematic vector env."""

import copy
import dataclasses
from typing import Any

from gymnasium.envs.registration import EnvSpec

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

    from snac_gym.envs.vector import task_vector_env_class, vector_env_supports

    hook = WrapperSpec(name="EpisodeLength", entry_point="snac_gym.envs.core:apply_episode_length", kwargs={})
    for task in TASKS.values():
        env_class = task_env_class(task)
        # The batched env steps end-effector positions only: a task with its own coordinates (a
        # pose task's PoseKinematics) gets no vector entry point, and make_vec falls back to sync.
        vector_class = task_vector_env_class(task) if vector_env_supports(task) else None
        ENV_IDS[task.env_id] = f"{env_class.__module__}:{env_class.__qualname__}"
        if task.env_id not in gym.registry:
            gym.register(
                id=task.env_id, entry_point=ENV_IDS[task.env_id], disable_env_checker=False,
                max_episode_steps=env_class.default_max_steps, additional_wrappers=(hook,),
                vector_entry_point=None if vector_class is None else f"{vector_class.__module__}:{vector_class.__qualname__}",
            )
            gym.registry[task.env_id] = _TaskEnvSpec(**_spec_fields(gym.registry[task.env_id]))


def _spec_fields(spec: Any) -> dict[str, Any]:
    """The constructor arguments of an ``EnvSpec``."""
    return {f.name: getattr(spec, f.name) for f in dataclasses.fields(spec) if f.init}


class _TaskEnvSpec(EnvSpec):
    """The registered spec of a task env: ``gym.make`` applies the episode-length hook, ``make_vec`` can vectorise.

    ``gym.make_vec(..., vectorization_mode="vector_entry_point")`` refuses a spec with
    ``additional_wrappers`` (wrappers cannot apply to a vector env), but ``gym.make`` needs the
    :func:`~snac_gym.envs.core.apply_episode_length` hook. ``make_vec`` works on a deep copy of
    the spec and ``make`` on the registered one, so the copy leaves the hook out: the vector env
    reads ``max_steps`` itself. (A ``make_vec(..., vectorization_mode="sync")`` therefore builds
    its sub-envs without the hook too: there ``max_steps`` above the registered length is cut
    to it by the ``TimeLimit``; pass ``max_episode_steps`` as well.)
    """

    def __deepcopy__(self, memo: dict[int, Any]) -> EnvSpec:
        fields = copy.deepcopy(_spec_fields(self), memo)
        fields["additional_wrappers"] = ()
        return EnvSpec(**fields)


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
