"""PPO's training view of the batched kinematic episodes: :class:`PPOVecEnv` (``vec_env.kind = "batched"``).

The same features, normalised actions, per-episode effort level and shaped reward as
:class:`~snac_gym.ppo.envs.PPOTrainingWrapper` around one env, computed for all N episodes at
once on :class:`~snac_gym.envs.sb3.SB3VectorEnv`. Episode for episode it is a ``DummyVecEnv``
of ``PPOTrainingWrapper``\\ s around single envs with ``physics="kinematic"``
(tests/envs/test_sb3.py): each episode's ``action_scale`` is drawn from that episode's own
generator right after its reset, as the wrapper draws it from its env's ``np_random``.
"""

from __future__ import annotations

from typing import Any, cast

import gymnasium as gym
import numpy as np

from snac_gym.envs.sb3 import SB3VectorEnv
from snac_gym.ppo.config import env_arguments
from snac_gym.ppo.envs import RewardSpec
from snac_gym.ppo.features import (
    EpisodeGoals,
    FeatureSpec,
    GoalState,
    action_size,
    feature_size,
    goal_relative_command,
    observation_features,
    task_relative_command,
)
from snac_gym.tasks import get_task


class PPOVecEnv(SB3VectorEnv):
    """N kinematic training episodes of a PPO config (see the module docs).

    Args:
        config: A resolved PPO config (:func:`snac_gym.ppo.config.resolve_config`): its task,
            robot, ``env`` arguments, ``features`` and ``reward``.
        num_envs: Number of episodes (default: ``vec_env.n_envs``).
    """

    def __init__(self, config: dict[str, Any], num_envs: int | None = None) -> None:
        self.features = FeatureSpec.from_dict(config["features"])
        self.reward_spec = RewardSpec.from_dict(config["reward"])
        count = int(num_envs if num_envs is not None else config["vec_env"].get("n_envs", 1))
        env_kwargs = {k: v for k, v in env_arguments(config).items() if k not in ("physics", "backend")}
        env_kwargs.update(self.reward_spec.env_kwargs())
        self.action_scales = np.ones(count)
        self.previous_actions = np.zeros((count, 1))
        super().__init__(get_task(config["task"]).env_id_for(config.get("robot", "ur10")), count, **env_kwargs)
        self.previous_actions = np.zeros((count, action_size(self.episodes.layout, self.features)))
        episodes = self.episodes
        kinematics = episodes.template.kinematics
        self._goals = (
            EpisodeGoals(kinematics, episodes.limits, episodes.dt, get_task(config["task"]).moving_reference, count)
            if self.features.goal_relative
            else None
        )
        self._goal: GoalState | None = None

    def _spaces(self) -> tuple[gym.spaces.Space, gym.spaces.Space]:
        layout = self.vector_env.episodes.layout
        observation = gym.spaces.Box(-np.inf, np.inf, shape=(feature_size(layout, self.features),), dtype=np.float32)
        return observation, gym.spaces.Box(-1.0, 1.0, shape=(action_size(layout, self.features),), dtype=np.float32)

    def _on_reset(self, indices: np.ndarray) -> None:
        self.previous_actions[indices] = 0.0
        if getattr(self, "_goals", None) is not None:
            cast(EpisodeGoals, self._goals).restart(indices)  # set (it is not while SB3VectorEnv.__init__ resets)
        low, high = self.features.action_scale_range
        for index in indices:
            generator = self.episodes.generators[index]
            self.action_scales[index] = (
                float(np.exp(generator.uniform(np.log(low), np.log(high)))) if high > low else low
            )

    def _features(self, observations: np.ndarray, rows: Any) -> np.ndarray:
        goal = None
        if self._goals is not None:
            goal = self._goals.observe(observations, self.episodes.layout, rows)
            if self._goal is None:
                self._goal = goal
            else:  # keep every row's current goal state for the next command
                self._goal.goal[rows], self._goal.velocity[rows] = goal.goal, goal.velocity
        features = observation_features(observations, self.episodes.layout, self.features, goal=goal)
        if not self.features.task_relative:
            features[:, -1] = np.log(self.action_scales[rows])  # the per-episode effort feature
        return features

    def _commands(self, actions: np.ndarray) -> np.ndarray:
        action = np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0)
        self._clipped = action
        limits = self.episodes.limits
        episodes = self.episodes
        if self.features.goal_relative:
            jacobians = episodes.template.kinematics.jacobian_batch(episodes.q)
            command = goal_relative_command(
                action,
                episodes.observations(),
                episodes.layout,
                jacobians,
                limits,
                self.features,
                cast(GoalState, self._goal),  # goal_relative: set by the reset's features
                self.action_scales[:, None],
            )
            return episodes.commands(command)
        if self.features.task_relative:
            jacobians = episodes.template.kinematics.jacobian_batch(episodes.q)
            command = task_relative_command(
                action,
                episodes.observations(),
                episodes.layout,
                jacobians,
                limits,
                self.features,
                self.action_scales[:, None],
            )
            return episodes.commands(command)
        # action_to_command with one action_scale per row, in the same order of operations.
        command = action * (limits * (self.features.action_fraction * self.action_scales[:, None]))
        return self.episodes.commands(np.minimum(np.maximum(command, -limits), limits))

    def _rewards(self, result: dict[str, np.ndarray], commands: np.ndarray) -> np.ndarray:
        rewards = self._task_rewards(result)
        if self.reward_spec.limit_penalty > 0:
            kinematics = self.episodes.template.kinematics
            rewards = rewards - self.reward_spec.limit_term(
                self.episodes.q, kinematics.lower_limits, kinematics.upper_limits, self.episodes.dt
            )
        return rewards

    def _task_rewards(self, result: dict[str, np.ndarray]) -> np.ndarray:
        action, previous = self._clipped, self.previous_actions
        self.previous_actions = action
        spec = self.reward_spec
        if spec.type != "shaped":
            return result["reward"]
        distance = result["error_norm"]
        change = action - previous
        return (
            -spec.distance_weight * distance
            + spec.precision_bonus * np.exp(-((distance / spec.precision_scale) ** 2))
            - spec.action_penalty * np.einsum("ij,ij->i", action, action)
            - spec.smoothness_penalty * np.einsum("ij,ij->i", change, change)
        )
