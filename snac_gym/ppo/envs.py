"""The training view of a snac-gym env: features in, normalised actions out, a shaped reward.

Each episode runs at an effort level ``action_scale`` drawn log-uniformly from the feature
spec's ``action_scale_range`` (with the env's seeded ``np_random``); the network sees it as a
feature and the command is scaled by it (:mod:`snac_gym.ppo.features`).

:class:`PPOTrainingWrapper` wraps ``snac_gym/UR10Reach-v0`` or ``snac_gym/UR10EllipseTrack-v0``
so that PPO sees exactly what :class:`~snac_gym.ppo.policy.PPOPolicy` will feed its network at
run time (:func:`~snac_gym.ppo.features.observation_features`) and acts in the normalised box
[−1, 1]ᵐ (:func:`~snac_gym.ppo.features.action_to_command`).

Training reward (``reward.type = "shaped"``, with d = ‖e‖ after the step and ``a`` the
normalised action)::

    r = −distance_weight · d + precision_bonus · exp(−(d / precision_scale)²)
        − action_penalty · ‖a‖² − smoothness_penalty · ‖a − a_prev‖²

(a_prev the previous normalised action, 0 after reset: the arm starts at rest). The distance
term pulls the end effector towards x_d from afar, the Gaussian bonus rewards settling within
``precision_scale`` (millimetres), which a term linear in d barely distinguishes, the action
penalty keeps the arm still once there, and the smoothness penalty stops the bang-bang
chatter around the target that the other terms alone lead to (and that the trajectory
cost's u̇ᵀRu̇ term punishes). With
``reward.type = "env"`` the env's own reward −(eᵀQe + uᵀRu) is used instead; with
``reward.type = "cost"`` the env's ``reward_type="cost"`` under the spec's ``cost``, ``q_scale`` and
``udot_start`` (the evaluator's ``--cost``, ``--q-scale``, ``--udot-start``): minus the step's share
of the trajectory cost PPO is scored by, so the return is −V. The env's reward is always kept in
``info["env_reward"]``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, cast

import gymnasium as gym
import numpy as np

from snac_gym.control.cost import CostConvention
from snac_gym.envs.core import TaskEnvCore, shaped_reward
from snac_gym.ppo.features import (
    EpisodeGoals,
    FeatureSpec,
    GoalState,
    action_size,
    command,
    feature_size,
    observation_features,
)

REWARD_TYPES = ("shaped", "env", "cost")


@dataclass(frozen=True)
class RewardSpec:
    """Weights of the training reward (see the module docstring).

    Attributes:
        type: ``"shaped"``, ``"env"`` or ``"cost"``.
        distance_weight: Weight of d, 1/m.
        precision_bonus: Height of the Gaussian bonus.
        precision_scale: Width of the bonus, m.
        action_penalty: Weight of ‖a‖².
        smoothness_penalty: Weight of ‖a − a_prev‖².
        cost, q_scale, udot_start: The cost convention of ``type="cost"``
        (:class:`~snac_gym.control.cost.CostConvention`).
        limit_penalty: Weight of the joint-limit term, 1/(rad·s): each step subtracts
            ``limit_penalty · Δt · Σⱼ (how far θⱼ is beyond its limit, rad)`` from the reward (0: none). The
            trajectory cost does not charge a crossing; the success rule fails it.
    """

    type: str = "shaped"
    distance_weight: float = 10.0
    precision_bonus: float = 1.0
    precision_scale: float = 0.01
    action_penalty: float = 0.01
    smoothness_penalty: float = 0.0
    cost: str = "hjb"
    q_scale: float = 1.0
    udot_start: str = "rest"
    limit_penalty: float = 0.0

    def __post_init__(self) -> None:
        if self.type not in REWARD_TYPES:
            raise ValueError(f"reward type must be one of {REWARD_TYPES}, got {self.type!r}")
        self.convention()  # a bad cost, q_scale or udot_start is refused here, naming it
        if not self.precision_scale > 0:
            raise ValueError(f"reward precision_scale must be positive, got {self.precision_scale}")
        if not (np.isfinite(self.limit_penalty) and self.limit_penalty >= 0):
            raise ValueError(f"reward limit_penalty must be a finite number ≥ 0, got {self.limit_penalty}")

    def limit_term(self, q: np.ndarray, lower: np.ndarray, upper: np.ndarray, dt: float) -> np.ndarray:
        """``limit_penalty · Δt · Σⱼ max(0, θ⁻ⱼ − θⱼ, θⱼ − θ⁺ⱼ)`` for ``q`` ``(m,)`` or ``(B, m)``."""
        beyond = np.maximum(0.0, np.maximum(lower - q, q - upper))
        return self.limit_penalty * dt * np.sum(beyond, axis=-1)

    def convention(self) -> CostConvention:
        """The cost convention of ``type="cost"``."""
        return CostConvention(self.cost, self.udot_start, self.q_scale)

    def env_kwargs(self) -> dict[str, Any]:
        """What the training env needs for this reward: ``reward_type="cost"`` and its convention, or nothing."""
        return {"reward_type": "cost", "cost": self.convention()} if self.type == "cost" else {}

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "RewardSpec":
        """Inverse of :meth:`to_dict`.

        Raises:
            ValueError: On unknown keys or bad values.
        """
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"reward spec: unknown keys {sorted(unknown)}")
        return cls(**data)

    def shaped(self, error_norm: float, action: np.ndarray, previous_action: np.ndarray) -> float:
        """The shaped reward for error norm ``error_norm`` (m) after a step taken with ``action``."""
        change = action - previous_action
        base = shaped_reward(
            error_norm, action, self.distance_weight, self.precision_bonus, self.precision_scale, self.action_penalty
        )
        return base - self.smoothness_penalty * float(change @ change)


class PPOTrainingWrapper(gym.Wrapper):
    """A snac-gym env as PPO trains on it (features, normalised actions, shaped reward).

    Args:
        env: A snac-gym env (``gym.make`` of a ``snac_gym/...`` id).
        features: The feature and action scales.
        reward: The training reward.
    """

    def __init__(self, env: gym.Env, features: FeatureSpec, reward: RewardSpec) -> None:
        super().__init__(env)
        base = cast(TaskEnvCore, env.unwrapped)  # a snac-gym env
        self.layout = base.obs_layout
        self.velocity_limits = np.asarray(base.velocity_limits, dtype=np.float64)
        self.features = features
        self.reward_spec = reward
        m = self.layout.n_joints
        self.kinematics = base.kinematics
        self.observation_space = gym.spaces.Box(
            -np.inf, np.inf, shape=(feature_size(self.layout, features),), dtype=np.float32
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(action_size(self.layout, features),), dtype=np.float32)
        self._last_obs: np.ndarray | None = None
        self._previous_action = np.zeros(m)
        self.action_scale = 1.0
        self.dt = float(base.dt)
        self._goals = (
            EpisodeGoals(self.kinematics, self.velocity_limits, self.dt, base.task.moving_reference, 1)
            if features.goal_relative
            else None
        )
        self._goal: GoalState | None = None

    def _features(self, obs: np.ndarray) -> np.ndarray:
        if self._goals is not None:
            self._goal = self._goals.observe(np.asarray(obs, dtype=np.float64)[None], self.layout).row(0)
        return observation_features(obs, self.layout, self.features, self.action_scale, self._goal)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self._previous_action = np.zeros(cast(gym.spaces.Box, self.action_space).shape[0])  # the Box of __init__
        self._last_obs = np.asarray(obs, dtype=np.float64)
        low, high = self.features.action_scale_range
        self.action_scale = float(np.exp(self.np_random.uniform(np.log(low), np.log(high)))) if high > low else low
        info["action_scale"] = self.action_scale
        if self._goals is not None:
            self._goals.restart()
        return self._features(obs), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        before = cast(np.ndarray, self._last_obs)  # set by reset()
        jacobian = self.kinematics.jacobian(before[self.layout.slices["q"]]) if self.features.task_relative else None
        joint_velocities = command(
            action, before, self.layout, self.velocity_limits, self.features, self.action_scale, jacobian, self._goal
        )
        obs, env_reward, terminated, truncated, info = self.env.step(joint_velocities)
        info["env_reward"] = env_reward
        if self.reward_spec.type == "shaped":
            reward = self.reward_spec.shaped(info["error_norm"], action, self._previous_action)
        else:
            reward = float(env_reward)
        if self.reward_spec.limit_penalty > 0:
            q = np.asarray(obs, dtype=np.float64)[self.layout.slices["q"]]
            reward -= float(
                self.reward_spec.limit_term(q, self.kinematics.lower_limits, self.kinematics.upper_limits, self.dt)
            )
        self._previous_action = action
        self._last_obs = np.asarray(obs, dtype=np.float64)
        return self._features(obs), reward, terminated, truncated, info
