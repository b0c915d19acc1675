"""A stable-baselines3 ``VecEnv`` on the batched kinematic episodes: PPO on thousands of episodes at once.

``PPO("MlpPolicy", SB3VectorEnv("snac_gym/UR10Reach-v0", num_envs=1024))`` trains on the
kinematic model (:mod:`snac_gym.envs.vector`) with one array operation per step for all
episodes, where a ``DummyVecEnv`` of single envs makes N Python calls.

It follows SB3's conventions, not Gymnasium's: autoreset happens in the same step (a finished
sub-env is reset at once and its last observation is in ``infos[i]["terminal_observation"]``,
``infos[i]["TimeLimit.truncated"]`` says whether it was cut by the episode length), rewards are
float32, ``seed(s)`` seeds sub-env i with ``s + i`` at the next ``reset()``. Episode for episode
it is a ``DummyVecEnv`` of single envs with ``physics="kinematic"`` (tests/envs/test_sb3.py).
To keep a step at array speed, ``infos[i]`` is empty except in the step where sub-env i's
episode ends: then it holds ``terminal_observation``, ``TimeLimit.truncated``, ``is_success`` and
``error_norm``. ``get_attr``/``set_attr``/``env_method`` reach the single env the vector env
was configured from (its arguments are shared by every sub-env).

Subclasses change what the learner sees through four hooks (:meth:`_features`,
:meth:`_commands`, :meth:`_rewards`, :meth:`_on_reset`); :class:`snac_gym.ppo.vec_env.PPOVecEnv`
is the PPO training view built that way.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any, cast

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from snac_gym.envs.vector import URTaskVectorEnv


class SB3VectorEnv(VecEnv):
    """SB3 ``VecEnv`` of ``num_envs`` kinematic episodes of ``env_id`` (see the module docs).

    Args:
        env_id: A registered snac-gym id (``snac_gym/UR10Reach-v0``, ...).
        num_envs: Number of episodes stepped at once.
        **env_kwargs: The single env's arguments (``max_steps``, ``action_type``, ...).
    """

    def __init__(self, env_id: str, num_envs: int, **env_kwargs: Any) -> None:
        vector = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **env_kwargs)
        self.vector_env: URTaskVectorEnv = cast(URTaskVectorEnv, vector.unwrapped)  # the ids' vector_entry_point
        self.episodes = self.vector_env.episodes
        self._actions: np.ndarray | None = None
        observation_space, action_space = self._spaces()
        super().__init__(self.vector_env.num_envs, observation_space, action_space)

    # -- hooks ---------------------------------------------------------------------------------
    def _spaces(self) -> tuple[gym.spaces.Space[Any], gym.spaces.Space[Any]]:
        """The observation and action spaces the learner sees (the single env's)."""
        return self.vector_env.single_observation_space, self.vector_env.single_action_space

    def _features(self, observations: np.ndarray, rows: Any) -> np.ndarray:
        """What the learner observes for episodes ``rows`` given their env observations."""
        return observations

    def _commands(self, actions: np.ndarray) -> np.ndarray:
        """Joint velocities (rad/s) for the learner's actions ``(N, m)``."""
        return self.episodes.commands(actions)

    def _rewards(self, result: dict[str, np.ndarray], commands: np.ndarray) -> np.ndarray:
        """The learner's rewards of a step (``result`` from :meth:`KinematicEpisodes.step`)."""
        return result["reward"]

    def _on_reset(self, indices: np.ndarray) -> None:
        """Called after episodes ``indices`` were reset (their generators have drawn the episode)."""

    # -- VecEnv --------------------------------------------------------------------------------
    def _reset_episodes(
        self, indices: Iterable[int], seeds: Sequence[int | None], options: Sequence[dict[str, Any]]
    ) -> None:
        indices = np.asarray(list(indices), dtype=np.intp)
        # An empty dict is no options, as DummyVecEnv passes it (an env given options={} would
        # start from the paper's reference). Without options all episodes reset in one batch.
        if not any(options):
            infos = self.episodes.reset(indices, seeds, None)
        else:
            infos = [
                self.episodes.reset([int(i)], [seed], option or None)[0]
                for i, seed, option in zip(indices, seeds, options, strict=True)
            ]
        for index, info in zip(indices, infos, strict=True):
            self.reset_infos[index] = info
        self._on_reset(indices)

    def reset(self) -> np.ndarray:
        self._reset_episodes(range(self.num_envs), self._seeds, self._options)
        self._reset_seeds()
        self._reset_options()
        return self._features(self.episodes.observations(), slice(None))

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        commands = self._commands(self._actions)
        self._actions = None
        result = self.episodes.step(commands)
        rewards = np.asarray(self._rewards(result, commands), dtype=np.float32)
        terminated, truncated = result["terminated"], result["truncated"]
        dones = terminated | truncated
        observations = self._features(self.episodes.observations(), slice(None))
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        if dones.any():
            ended = np.flatnonzero(dones)
            for i in ended:
                infos[i] = {
                    "terminal_observation": observations[i].copy(),
                    "TimeLimit.truncated": bool(truncated[i] and not terminated[i]),
                    "is_success": bool(result["is_success"][i]),
                    "error_norm": float(result["error_norm"][i]),
                }
            self._reset_episodes(ended, [None] * len(ended), [{}] * len(ended))
            observations[ended] = self._features(self.episodes.observations(ended), ended)
        return observations, rewards, dones, infos

    def close(self) -> None:
        self.vector_env.close()

    def _indices(self, indices: VecEnvIndices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        if isinstance(indices, int):
            return [indices]
        return list(indices)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        value = getattr(self.vector_env.single_env, attr_name)
        return [value for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        if self._indices(indices) != list(range(self.num_envs)):
            raise ValueError("the sub-envs share one configuration: set_attr applies to all of them (indices=None)")
        setattr(self.vector_env.single_env, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        method = getattr(self.vector_env.single_env, method_name)
        return [method(*method_args, **method_kwargs) for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        del wrapper_class  # SB3's signature: the sub-envs are rows of one batched env, wrapped by nothing
        return [False for _ in self._indices(indices)]
