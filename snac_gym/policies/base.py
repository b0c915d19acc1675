"""The policy interface every controller of snac-gym implements.

A policy is built from the env it will drive (:class:`PolicyContext` collects what it may
take from there: the shared kinematics, the control period, the limits, the observation
layout and the task), then driven with ``reset(seed)`` and ``act(obs)``. The same object
drives the PyBullet env, the evaluator's kinematic backend and the real robot.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from snac_gym.kinematics import Kinematics
from snac_gym.observation import ObservationLayout

TASKS = ("reach", "track")


def positive_float(name: str, value: Any) -> float:
    """``value`` as a finite float > 0.

    Raises:
        ValueError: If it is not one.
    """
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a positive number, got {value!r}") from exc
    if not (np.isfinite(number) and number > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return number


@runtime_checkable
class Policy(Protocol):
    """What the envs, the evaluator and the real-robot loop need from a controller.

    Attributes:
        internals: A dict of named arrays describing the policy's state after the last
            ``act`` call (for example ``critic_weights`` and ``lyapunov`` for SNAC), read by
            the trajectory logs. Empty for policies with nothing to expose.
    """

    internals: dict[str, Any]

    def reset(self, seed: int | None = None) -> None:
        """Start a new episode; ``seed`` fixes any randomness (e.g. initial critic weights)."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command u (rad/s, shape ``(n_joints,)``) for observation ``obs``."""


@dataclass(frozen=True)
class PolicyContext:
    """What a policy takes from the env it drives.

    Attributes:
        kinematics: The shared :class:`~snac_gym.kinematics.Kinematics`.
        dt: Control period, s.
        velocity_limits: Joint speed limits, rad/s (the action bounds).
        layout: The observation layout.
        task: ``"reach"`` or ``"track"``.
    """

    kinematics: Kinematics
    dt: float
    velocity_limits: np.ndarray
    layout: ObservationLayout
    task: str

    def __post_init__(self) -> None:
        if self.task not in TASKS:
            raise ValueError(f"task must be one of {TASKS}, got {self.task!r}")
        if not self.dt > 0:
            raise ValueError(f"dt must be positive, got {self.dt}")

    @classmethod
    def from_env(cls, env: Any) -> "PolicyContext":
        """Read the context from a snac-gym env (wrapped or not) or from a context itself."""
        if isinstance(env, PolicyContext):
            return env
        base = getattr(env, "unwrapped", env)
        missing = [a for a in ("kinematics", "dt", "velocity_limits", "obs_layout", "task_name") if not hasattr(base, a)]
        if missing:
            raise TypeError(f"{type(base).__name__} is not a snac-gym env: it lacks {missing}")
        return cls(base.kinematics, float(base.dt), np.asarray(base.velocity_limits, float), base.obs_layout, base.task_name)


class BasePolicy:
    """Convenience base class: stores the context and gives ``internals`` a default."""

    def __init__(self, env: Any) -> None:
        self.context = PolicyContext.from_env(env)
        self.kinematics = self.context.kinematics
        self.dt = self.context.dt
        self.velocity_limits = self.context.velocity_limits
        self.layout = self.context.layout
        self.task = self.context.task
        self.internals: dict[str, Any] = {}

    def reset(self, seed: int | None = None) -> None:
        self.internals = {}

    def act(self, obs: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError
