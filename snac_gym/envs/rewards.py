"""The env's rewards beside the dense one: the shaped reward (the PPO training wrapper's too) and the cost reward's
convention.

The single env (:mod:`snac_gym.envs.core`), the batched vector env (:mod:`snac_gym.envs.vector`) and the PPO wrapper
(:mod:`snac_gym.ppo.envs`) share them, so a reward type means one thing everywhere.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, overload

import numpy as np

from snac_gym.control.cost import CostConvention

__all__ = ["REWARD_TYPES", "SHAPED_REWARD", "cost_reward_convention", "shaped_reward"]

#: Reward types (see the env docstrings, "Rewards").
REWARD_TYPES = ("dense", "sparse", "shaped", "cost")
#: Weights of ``reward_type="shaped"``: r = −distance_weight·d + precision_bonus·exp(−(d/precision_scale)²)
#: − action_penalty·‖a‖², the defaults of :class:`snac_gym.ppo.envs.RewardSpec`.
SHAPED_REWARD: Mapping[str, float] = MappingProxyType(
    {"distance_weight": 10.0, "precision_bonus": 1.0, "precision_scale": 0.01, "action_penalty": 0.01}
)


@overload
def shaped_reward(
    error_norm: float,
    action: np.ndarray,
    distance_weight: float = ...,
    precision_bonus: float = ...,
    precision_scale: float = ...,
    action_penalty: float = ...,
) -> float: ...


@overload
def shaped_reward(
    error_norm: np.ndarray,
    action: np.ndarray,
    distance_weight: float = ...,
    precision_bonus: float = ...,
    precision_scale: float = ...,
    action_penalty: float = ...,
) -> np.ndarray: ...


def shaped_reward(
    error_norm: float | np.ndarray,
    action: np.ndarray,
    distance_weight: float = SHAPED_REWARD["distance_weight"],
    precision_bonus: float = SHAPED_REWARD["precision_bonus"],
    precision_scale: float = SHAPED_REWARD["precision_scale"],
    action_penalty: float = SHAPED_REWARD["action_penalty"],
) -> float | np.ndarray:
    """The ``reward_type="shaped"`` reward; the PPO training wrapper uses the same function.

    One step (a float), or the rows of a batch (the vector env): ``error_norm`` ``(B,)`` and ``action`` ``(B, m)``
    (an array ``(B,)``).

    Args:
        error_norm: d = ‖e‖ after the step, m.
        action: The applied command normalised to [−1, 1] (u / v_max).
        distance_weight, precision_bonus, precision_scale, action_penalty: The weights
            (default :data:`SHAPED_REWARD`).

    Returns:
        −distance_weight·d + precision_bonus·exp(−(d / precision_scale)²) − action_penalty·‖a‖².
    """
    bonus = precision_bonus * np.exp(-((error_norm / precision_scale) ** 2))
    reward: float | np.ndarray = (
        -distance_weight * error_norm + bonus - action_penalty * np.einsum("...i,...i->...", action, action)
    )
    return reward


def cost_reward_convention(reward_type: str, cost: CostConvention | None, Q: Any, R: Any) -> CostConvention | None:
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
