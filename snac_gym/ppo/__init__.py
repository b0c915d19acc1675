"""The PPO learning baseline: training (``snac-gym train-ppo``) and the ``ppo`` policy.

* :mod:`snac_gym.ppo.features`: what the network sees (features of the observation only)
  and what its action means (a fraction of the velocity limits).
* :mod:`snac_gym.ppo.envs`: the training wrapper (features, normalised actions, shaped reward).
* :mod:`snac_gym.ppo.config`: the versioned JSON hyperparameter files in ``configs/``.
* :mod:`snac_gym.ppo.train`: :func:`~snac_gym.ppo.train.train_ppo` (needs the ``rl`` extra).
* :mod:`snac_gym.ppo.policy_file`: the frozen, NumPy-only policy file format.
* :mod:`snac_gym.ppo.policy`: :class:`~snac_gym.ppo.policy.PPOPolicy`, registered as ``ppo``;
  it loads the policy file shipped in ``models/`` for the env's task by default;
  :class:`~snac_gym.ppo.policy.WorkspacePPOPolicy` (``ppo-workspace``) is withdrawn: it ships no file and
  runs only a goal-relative policy file it is given (docs/ppo.md).
* :mod:`snac_gym.ppo.cloning`: behaviour cloning of the reference into a goal-relative actor.

Importing this package does not import torch or stable-baselines3.
"""

from snac_gym.ppo.policy import PPOPolicy, WorkspacePPOPolicy, shipped_model_path
from snac_gym.ppo.policy_file import MissingPolicyFileError, PolicyFile, PolicyFileError

__all__ = [
    "MissingPolicyFileError",
    "PPOPolicy",
    "PolicyFile",
    "PolicyFileError",
    "WorkspacePPOPolicy",
    "shipped_model_path",
]
