"""``make_policy("ppo", env)``: a PPO policy trained with ``snac-gym train-ppo``, run exactly.

The policy reads a policy file (:mod:`snac_gym.ppo.policy_file`): by default the one shipped
for the env's task (``snac_gym/ppo/models/<task>.npz``), so it works right after install,
without torch, stable-baselines3 or any training. The observation normalisation is the one
frozen at export; ``act`` returns the deterministic (mean) action, computed from the
observation alone (:func:`~snac_gym.ppo.features.observation_features`).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from snac_gym.policies.base import BasePolicy, positive_float
from snac_gym.ppo.features import EpisodeGoals
from snac_gym.ppo.policy_file import MissingPolicyFileError, PolicyFile, PolicyFileError

#: Package whose ``models/`` folder holds the shipped policy files.
PACKAGE = "snac_gym.ppo"


def shipped_model_path(task: str, folder: str = "models") -> Path:
    """Path of the policy file shipped for ``task`` (``reach`` or ``track``) in ``folder`` of the package
    (``models``: ``ppo``'s)."""
    return Path(str(resources.files(PACKAGE).joinpath(*folder.split("/"), f"{task}.npz")))


class PPOPolicy(BasePolicy):
    """Deterministic PPO actor on the features of the observation.

    ``u = action_scale · action_fraction · clip(π(normalise(features(obs, action_scale))), −1, 1) ⊙ ū``,
    with π the actor's mean, the normalisation frozen from training and ū the velocity limits
    (the result clipped to ±ū). The network sees ``ln(action_scale)``: it was trained over a
    range of scales (``model.features.action_scale_range``, 0.5–4 for the shipped files), so
    the knob raises the effort without destabilising the loop near the target.

    Args:
        env: The env (or :class:`~snac_gym.policies.base.PolicyContext`) to drive.
        model_path: A policy file written by ``snac-gym train-ppo`` (``best/policy.npz`` of
            its output); default: the file shipped for the env's task.
        action_scale: The effort knob (:attr:`effort_parameter`): scales the command and is
            an input of the network; 1 is the default. Values outside the trained range
            extrapolate.

    Raises:
        MissingPolicyFileError: If the file does not exist.
        PolicyFileError: If it is corrupt, was trained for another task, robot or
            observation layout, or its model card ``<stem>.json`` (if any) describes another file.
        ValueError: If ``action_scale`` is not a positive finite number.

    Attributes:
        effort_parameter: ``"action_scale"``, for the evaluator's equal-effort matching.
        model: The loaded :class:`~snac_gym.ppo.policy_file.PolicyFile`.
    """

    effort_parameter = "action_scale"
    #: Package folder of the default policy files.
    models_folder = "models"

    def __init__(self, env: Any, model_path: str | Path | None = None, action_scale: float = 1.0) -> None:
        super().__init__(env)
        self.action_scale = positive_float("action_scale", action_scale)
        self.model_path = (
            Path(model_path) if model_path is not None else shipped_model_path(self.task, self.models_folder)
        )
        self.model = PolicyFile.load(self.model_path)
        self.model.check_compatible(
            self.task, self.layout, self.context.arm_robot, source=f"PPO policy file {self.model_path}"
        )
        self.model.check_card(self.model_path)
        self._obs_size = self.layout.size
        self._q = self.layout.slices["q"]
        # The task-relative policies map their task-space action through the model's J(θ).
        self._task_relative = self.model.features.task_relative
        # The goal-relative ones also keep a goal configuration per episode (solved at its first step).
        self._goals: EpisodeGoals | None = None

    @property
    def input_files(self) -> tuple[Path, ...]:
        """Files whose content decides the commands (hashed by the evaluator's ``run.json``)."""
        return (self.model_path,)

    def reset(self, seed: int | None = None) -> None:
        """Start an episode (the policy is deterministic; ``seed`` is unused; a goal-relative policy solves its
        goal at the next step)."""
        self.internals = {}
        self._goals = None

    def _goal_state(self, obs_batch: np.ndarray) -> Any:
        if not self.model.features.goal_relative:
            return None
        if self._goals is None or len(self._goals.pending) != len(obs_batch):
            self._goals = EpisodeGoals(self.kinematics, self.velocity_limits, self.dt, self.tracking, len(obs_batch))
        return self._goals.observe(obs_batch, self.layout)

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command (rad/s, shape ``(m,)``) for one observation.

        Raises:
            ValueError: If ``obs`` does not have the layout's shape.
        """
        obs = np.asarray(obs, dtype=np.float64)
        if obs.shape != (self._obs_size,):
            raise ValueError(f"observation must have shape ({self._obs_size},), got {obs.shape}")
        jacobian = self.kinematics.jacobian(obs[self._q]) if self._task_relative else None
        goal = self._goal_state(obs[None])
        goal = None if goal is None else goal.row(0)
        return self.model.command(obs, self.layout, self.velocity_limits, self.action_scale, jacobian, goal)

    # -- the evaluator's optional batch protocol (snac_gym.policies.base) ------------------------
    def reset_batch(self, seeds: Sequence[int]) -> None:
        """Start B episodes (as :meth:`reset`)."""
        self.reset()

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)`` for observations ``(B, d)``; row i equals ``act(obs_batch[i])``."""
        obs_batch = np.asarray(obs_batch, dtype=np.float64)
        if obs_batch.ndim != 2 or obs_batch.shape[1] != self._obs_size:
            raise ValueError(f"observations must have shape (B, {self._obs_size}), got {obs_batch.shape}")
        jacobians = (
            self.kinematics.jacobian_batch(np.ascontiguousarray(obs_batch[:, self._q])) if self._task_relative else None
        )
        goal = self._goal_state(obs_batch)
        return self.model.command(obs_batch, self.layout, self.velocity_limits, self.action_scale, jacobians, goal)


#: Why ``ppo-workspace`` ships no policy (docs/ppo.md, "ppo-workspace: withdrawn").
WITHDRAWN = (
    "ppo-workspace is withdrawn: no learned correction beat joint-goal, the controller it corrects (the PPO policy "
    "cost 1.00-1.01x joint-goal on the whole reach; clones of the reference and PPO from them did worse: "
    "docs/ppo.md); use joint-goal, or pass ppo-workspace.model_path=FILE for a goal-relative policy of your own"
)


class WorkspacePPOPolicy(PPOPolicy):
    """``ppo-workspace``: a goal-relative :class:`PPOPolicy` on the arm's whole reach; withdrawn, so it needs a file.

    Goal-relative policies (:mod:`snac_gym.ppo.features`): the network corrects the ``joint-goal``
    controller (straight joint-space motion to the in-limit IK solution nearest the start), so it keeps
    the joint limits where the task-relative ``ppo`` leaves them. Trained with
    ``snac_gym/ppo/configs/goal/<task>.json``. No policy ships: none trained or cloned beat ``joint-goal``
    (:data:`WITHDRAWN`), so ``model_path`` is required.

    Raises:
        MissingPolicyFileError: Without ``model_path`` (:data:`WITHDRAWN`); and as :class:`PPOPolicy` does.
    """

    def __init__(self, env: Any, model_path: str | Path | None = None, action_scale: float = 1.0) -> None:
        if model_path is None:
            raise MissingPolicyFileError(WITHDRAWN)  # no file ships (a registry test skips a missing model)
        super().__init__(env, model_path, action_scale)


__all__ = ["WITHDRAWN", "PPOPolicy", "PolicyFileError", "WorkspacePPOPolicy", "shipped_model_path"]
