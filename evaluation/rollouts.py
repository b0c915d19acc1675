"""Moved: :mod:`snac_gym.rollout.batch` (re-exported here until every importer has moved)."""

from snac_gym.rollout.batch import Rollouts, rollouts_from_logs, summarise_critic_diagnostics  # noqa: F401
