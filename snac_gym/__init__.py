"""snac-gym: the single network adaptive critic (SNAC) kinematic controller of Menon, Prakash and
Behera, its baselines and the paper's evaluation, on Gymnasium UR arm environments.

Importing the package registers one environment id per robot and task, ``snac_gym/UR10Reach-v0``,
``snac_gym/UR10EllipseTrack-v0``, ``snac_gym/PandaReach-v0``, ... (:mod:`snac_gym.envs.ids`), each
with its goal-conditioned variant ``snac_gym/UR10ReachGoal-v0``, ... (:mod:`snac_gym.envs.goal`).
"""

from snac_gym.common import _renamed
from snac_gym.control.cost import CostTerms, instantaneous_cost, trajectory_cost
from snac_gym.envs import ENV_IDS, register_envs
from snac_gym.model.kinematics import Kinematics
from snac_gym.observation import ObservationLayout
from snac_gym.policies import Policy, PolicyContext, available_policies, make_policy, register_policy
from snac_gym.references import Ellipse, FixedTarget

__version__ = "0.2.0"

register_envs()
_renamed.install()  # `import evaluation` (0.1.0's name) says where it went

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
