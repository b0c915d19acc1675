"""The goal error as a feature of a goal-conditioned policy: ``GoalErrorExtractor`` for SB3's ``MultiInputPolicy``.

A goal env's observation holds the tool position and the goal as two vectors of about 1 m. A
1 mm reach asks the network to resolve their difference to 1e-3 of their size, which an MLP on
the raw inputs learns slowly (SAC+HER on the 1 mm reach: docs/rl.md). This extractor computes
the difference ``d = desired_goal − achieved_goal`` inside the network and adds it at three
scales, ``d / 0.1 m``, ``tanh(d / 1 cm)`` and ``tanh(d / 1 mm)``, to the concatenated inputs.

It is computed from the observation the policy is given, so HER's relabelled goals stay
consistent: a replayed transition with a new goal gets the features of that goal. (An action
scaled by the error, PPO's choice in :mod:`snac_gym.ppo.features`, would not be: the same
stored action would mean another velocity under another goal.)

Use: ``SAC("MultiInputPolicy", env, policy_kwargs={"features_extractor_class": GoalErrorExtractor})``.
Needs the ``rl`` extra (torch, stable-baselines3).
"""

from __future__ import annotations

from typing import cast

import gymnasium as gym
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

#: Length scales (m) of the goal-error features: ``d / SCALES[0]`` and ``tanh(d / s)`` for the others.
SCALES = (0.1, 0.01, 0.001)


class GoalErrorExtractor(BaseFeaturesExtractor):
    """Concatenates ``observation``, ``achieved_goal``, ``desired_goal`` and the goal error at :data:`SCALES`.

    Args:
        observation_space: A goal env's ``Dict`` space with ``observation``, ``achieved_goal``
            and ``desired_goal`` boxes (the two goals of one shape).

    Raises:
        ValueError: If a key is missing or the goal boxes differ in shape.
    """

    def __init__(self, observation_space: gym.spaces.Dict) -> None:
        keys = ("observation", "achieved_goal", "desired_goal")
        missing = [key for key in keys if key not in observation_space.spaces]
        if missing:
            raise ValueError(f"GoalErrorExtractor needs a goal env's Dict space; missing {', '.join(missing)}")
        spaces = observation_space.spaces
        if spaces["achieved_goal"].shape != spaces["desired_goal"].shape:
            raise ValueError(
                f"achieved_goal {spaces['achieved_goal'].shape} and desired_goal {spaces['desired_goal'].shape} differ"
            )
        goal = int(cast(gym.spaces.Box, spaces["desired_goal"]).shape[0])  # Box spaces (a Box's shape is set)
        size = int(cast(gym.spaces.Box, spaces["observation"]).shape[0]) + 2 * goal + len(SCALES) * goal
        super().__init__(observation_space, features_dim=size)

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        error = observations["desired_goal"] - observations["achieved_goal"]
        scaled = [error / SCALES[0]] + [torch.tanh(error / scale) for scale in SCALES[1:]]
        parts = [observations["observation"], observations["achieved_goal"], observations["desired_goal"], *scaled]
        return torch.cat([part.flatten(1) for part in parts], dim=1)


__all__ = ["SCALES", "GoalErrorExtractor"]
