"""The real-robot path: a Gymnasium env over a UR arm (ur_rtde), its safety layer, and a
simulated backend to rehearse the whole loop without hardware."""

from snac_gym.real.backends import (
    EMERGENCY_STOP,
    NORMAL,
    PROTECTIVE_STOP,
    ArmBackend,
    ConnectionFailure,
    DryRunBackend,
    SimulatedBackend,
    URRTDEBackend,
)
from snac_gym.real.env import RealUREnv
from snac_gym.real.safety import SafetyLayer, SafetyLimits

__all__ = [
    "EMERGENCY_STOP",
    "NORMAL",
    "PROTECTIVE_STOP",
    "ArmBackend",
    "ConnectionFailure",
    "DryRunBackend",
    "RealUREnv",
    "SafetyLayer",
    "SafetyLimits",
    "SimulatedBackend",
    "URRTDEBackend",
]
