"""Moved: the rollout engines live in :mod:`snac_gym.rollout` (this module re-exports them until
every importer has moved)."""

from evaluation.jobs import BACKENDS
from snac_gym.rollout import RolloutError, simulate_kinematic, simulate_pybullet
from snac_gym.rollout.kinematic import DIAGNOSTIC_STRIDE

__all__ = ["BACKENDS", "DIAGNOSTIC_STRIDE", "RolloutError", "simulate_kinematic", "simulate_pybullet"]
