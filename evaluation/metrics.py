"""Moved: :mod:`snac_gym.metrics` (re-exported here until every importer has moved)."""

from snac_gym.metrics import *  # noqa: F403
from snac_gym.metrics import REACH_TOLERANCE, TRACK_TOLERANCE, rollout_metrics  # noqa: F401
