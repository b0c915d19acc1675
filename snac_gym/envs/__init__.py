"""Gymnasium environments: a PyBullet UR arm under joint-velocity control."""

from snac_gym.envs.core import UR10EllipseTrackEnv, UR10ReachEnv, URTaskEnv

#: Registered ids and their classes (registered in one loop by :func:`register_envs`).
ENV_IDS = {
    "snac_gym/UR10Reach-v0": "snac_gym.envs.core:UR10ReachEnv",
    "snac_gym/UR10EllipseTrack-v0": "snac_gym.envs.core:UR10EllipseTrackEnv",
}


def register_envs() -> None:
    """Register every id of :data:`ENV_IDS` with Gymnasium (idempotent)."""
    import gymnasium as gym

    for env_id, entry_point in ENV_IDS.items():
        if env_id not in gym.registry:
            # The env truncates itself after max_steps, so no TimeLimit wrapper is added.
            gym.register(id=env_id, entry_point=entry_point, disable_env_checker=False)


__all__ = ["ENV_IDS", "UR10EllipseTrackEnv", "UR10ReachEnv", "URTaskEnv", "register_envs"]
