"""snac-gym: the single network adaptive critic (SNAC) kinematic controller of Menon, Prakash and
Behera, its baselines and the paper's evaluation, on Gymnasium UR arm environments.

Importing the package registers the environments ``snac_gym/UR10Reach-v0`` and
``snac_gym/UR10EllipseTrack-v0`` and their goal-conditioned variants ``snac_gym/UR10ReachGoal-v0``
and ``snac_gym/UR10EllipseTrackGoal-v0`` (:mod:`snac_gym.envs.goal`).
"""

from snac_gym.cost import CostTerms, instantaneous_cost, trajectory_cost
from snac_gym.envs import ENV_IDS, register_envs
from snac_gym.envs.goal import register_goal_envs
from snac_gym.kinematics import Kinematics
from snac_gym.observation import ObservationLayout
from snac_gym.policies import Policy, PolicyContext, available_policies, make_policy, register_policy
from snac_gym.references import Ellipse, FixedTarget

__version__ = "0.1.0"

register_envs()
register_goal_envs()

__all__ = [
    "ENV_IDS",
    "CostTerms",
    "Ellipse",
    "FixedTarget",
    "Kinematics",
    "ObservationLayout",
    "Policy",
    "PolicyContext",
    "__version__",
    "available_policies",
    "instantaneous_cost",
    "make_policy",
    "register_policy",
    "trajectory_cost",
]
