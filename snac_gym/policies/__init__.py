"""Controllers and the interface they share."""

from snac_gym.policies.base import BasePolicy, Policy, PolicyContext
from snac_gym.policies.registry import ENTRY_POINT_GROUP, available_policies, make_policy, register_policy
from snac_gym.policies.units import EnvUnitsPolicy

__all__ = [
    "BasePolicy",
    "ENTRY_POINT_GROUP",
    "EnvUnitsPolicy",
    "Policy",
    "PolicyContext",
    "available_policies",
    "make_policy",
    "register_policy",
]
