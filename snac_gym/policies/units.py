"""A controller in physical units driving an env whose spaces are scaled (the -v1 ids).

The controllers compute in physical units: float64 observations, joint velocities u in rad/s. A -v1 id
(docs/environments.md, "v1 vs v0") observes in float32 and takes the normalized action a = u / ū ∈ [−1, 1]
(ū the arm's joint velocity limits), which the env maps back to u = a·ū. :func:`~snac_gym.policies.make_policy`
wraps the controller it builds for such an env in :class:`EnvUnitsPolicy`, so that ``act(obs)`` takes the env's
observation and returns the env's action, and the same loop drives a -v0 and a -v1 id::

    env = gym.make("snac_gym/UR10Reach-v1")
    policy = make_policy("snac", env)        # EnvUnitsPolicy around SNACPolicy
    obs, info = env.reset(seed=0)
    obs, *_ = env.step(policy.act(obs))      # a = u / ū, float32

The evaluator, the demo and the real arm build their controllers from a :class:`PolicyContext` or a
-v0 env (physical units): nothing is wrapped there.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # the annotation only: base imports the kinematics, which this module does not need
    from snac_gym.policies.base import Policy


class EnvUnitsPolicy:
    """``policy`` (physical units) seen through an env's scaling: float64 observations in, normalized actions out.

    Args:
        policy: The controller, computing u (rad/s) from a float64 observation.
        velocity_limits: ū, rad/s: a = u / ū, clipped to [−1, 1] (what the env would clip it to).
        action_dtype: The env's action dtype (float32 for a normalized action).
        normalized: Whether the env's action is normalized (``False``: u itself, only the observation is cast).

    Attributes:
        policy: The wrapped controller (its attributes are also read through this object:
            ``internals``, ``critic_weights``, ...).
    """

    def __init__(
        self, policy: Policy, velocity_limits: np.ndarray, action_dtype: Any = np.float32, normalized: bool = True
    ) -> None:
        self.policy = policy
        self.velocity_limits = np.asarray(velocity_limits, dtype=np.float64).copy()
        self.action_dtype = np.dtype(action_dtype)
        self.normalized = bool(normalized)

    def reset(self, seed: int | None = None) -> None:
        self.policy.reset(seed=seed)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The env's action for the env's observation ``obs``."""
        return self.to_action(self.policy.act(np.asarray(obs, dtype=np.float64)))

    def to_action(self, u: np.ndarray) -> np.ndarray:
        """The env's action for the command ``u`` (rad/s; rows of a batch too)."""
        u = np.asarray(u, dtype=np.float64)
        if self.normalized:
            u = np.clip(u / self.velocity_limits, -1.0, 1.0)
        return u.astype(self.action_dtype)

    def to_command(self, action: np.ndarray) -> np.ndarray:
        """The command u (rad/s, float64) the env applies for ``action`` (clipped as the env clips it)."""
        a = np.asarray(action, dtype=np.float64)
        if self.normalized:
            return np.clip(a, -1.0, 1.0) * self.velocity_limits
        return np.clip(a, -self.velocity_limits, self.velocity_limits)

    @property
    def internals(self) -> dict[str, Any]:
        return self.policy.internals

    def __getattr__(self, name: str) -> Any:
        # Only reached for what this class lacks: the controller's own attributes. The batch protocol is
        # scaled like act (reset_batch passes through); a missing one stays missing (supports_batch reads it).
        if name.startswith("__") or "policy" not in self.__dict__:
            raise AttributeError(name)
        value = getattr(self.policy, name)
        if name == "act_batch":
            return lambda obs_batch: self.to_action(value(np.asarray(obs_batch, dtype=np.float64)))
        return value

    def __repr__(self) -> str:
        scaling = "a = u / velocity_limits" if self.normalized else "u"
        return f"EnvUnitsPolicy({self.policy!r}, {scaling}, {self.action_dtype})"


def for_env(policy: Any, env: Any) -> Any:
    """``policy`` as it must drive ``env``: itself for an env in physical units (a -v0 id, a
    :class:`~snac_gym.policies.base.PolicyContext`), else wrapped in :class:`EnvUnitsPolicy`."""
    base = getattr(env, "unwrapped", env)
    normalized = getattr(base, "action_type", "velocity") == "normalized"
    obs_dtype = getattr(base, "observation_dtype", None)
    float32_obs = obs_dtype is not None and np.dtype(obs_dtype) != np.float64
    if not (normalized or float32_obs):
        return policy
    action_space = getattr(base, "action_space", None)
    action_dtype = getattr(action_space, "dtype", None) or (np.float32 if normalized else np.float64)
    return EnvUnitsPolicy(policy, base.velocity_limits, action_dtype, normalized)
