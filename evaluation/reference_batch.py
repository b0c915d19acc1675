"""Moved: :func:`snac_gym.rollout.kinematic.reference_trajectories`."""

from snac_gym.rollout.kinematic import reference_trajectories  # noqa: F401
