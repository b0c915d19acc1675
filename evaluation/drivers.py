"""Moved: the batch protocol is part of the controller contract, :mod:`snac_gym.policies.base`."""

from snac_gym.policies.base import LockstepPolicies, supports_batch  # noqa: F401
