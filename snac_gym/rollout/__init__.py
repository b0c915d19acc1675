"""The rollout engine: one episode or a batch, env-stepped or on the exact kinematic model.

* :func:`rollout` (:mod:`.episode`): one episode of a policy in a snac-gym env (PyBullet or
  the real robot), logged row by row; the demo, the real run and PPO evaluation use it.
* :func:`simulate_kinematic` (:mod:`.kinematic`): B samples in lockstep on θₖ₊₁ = θₖ + uₖΔt,
  the evaluator's default engine and the SNAC studies'.
* :func:`simulate_arms` (:mod:`.kinematic`): the same lockstep loop on one simulated arm per
  sample (:func:`lockstep_arms`: MuJoCo or PyBullet), the evaluator's physics engines.
* :func:`simulate_env` (:mod:`.episode`): B samples one after the other in the env (PyBullet or MuJoCo),
  the demo's loop; the reference the lockstep path is tested against.
* :class:`Rollouts` (:mod:`.batch`): what both batch engines return, measured by
  :func:`snac_gym.metrics.rollout_metrics`; :mod:`.log` holds the per-step log format.
"""

from snac_gym.rollout.batch import RolloutError, Rollouts, rollouts_from_logs, summarise_critic_diagnostics
from snac_gym.rollout.episode import lockstep_arms, partial_log, rollout, simulate_env
from snac_gym.rollout.kinematic import reference_trajectories, simulate_arms, simulate_kinematic
from snac_gym.rollout.log import add_critic_diagnostics, log_array, log_columns, read_log, vector_columns, write_log

__all__ = [
    "RolloutError",
    "Rollouts",
    "add_critic_diagnostics",
    "lockstep_arms",
    "log_array",
    "log_columns",
    "partial_log",
    "read_log",
    "reference_trajectories",
    "rollout",
    "rollouts_from_logs",
    "simulate_arms",
    "simulate_kinematic",
    "simulate_env",
    "summarise_critic_diagnostics",
    "vector_columns",
    "write_log",
]
