"""Gymnasium environments: a PyBullet UR arm under joint-velocity control."""

from snac_gym.envs.core import (
    ACTION_TYPES,
    REWARD_TYPES,
    SHAPED_REWARD,
    UR10EllipseTrackEnv,
    UR10ReachEnv,
    URTaskEnv,
    shaped_reward,
)

#: Registered ids and their classes (registered in one loop by :func:`register_envs`).
ENV_IDS = {
    "snac_gym/UR10Reach-v0": "snac_gym.envs.core:UR10ReachEnv",
    "snac_gym/UR10EllipseTrack-v0": "snac_gym.envs.core:UR10EllipseTrackEnv",
}


def register_envs() -> None:
    """Register every id of :data:`ENV_IDS` with Gymnasium (idempotent).

    Each id's episode length is its class's ``default_max_steps``, registered as
    ``max_episode_steps`` (the ``TimeLimit`` wrapper ``gym.make`` adds); the registered
    :func:`~snac_gym.envs.core.apply_episode_length` hook lets the ``max_steps`` argument set it.
    """
    import gymnasium as gym
    from gymnasium.envs.registration import WrapperSpec

    classes = {"snac_gym.envs.core:UR10ReachEnv": UR10ReachEnv, "snac_gym.envs.core:UR10EllipseTrackEnv": UR10EllipseTrackEnv}
    hook = WrapperSpec(name="EpisodeLength", entry_point="snac_gym.envs.core:apply_episode_length", kwargs={})
    for env_id, entry_point in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(
                id=env_id, entry_point=entry_point, disable_env_checker=False,
                max_episode_steps=classes[entry_point].default_max_steps, additional_wrappers=(hook,),
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
]
