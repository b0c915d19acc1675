"""The real-robot path: a Gymnasium env over a UR arm (ur_rtde), its safety layer, and a
simulated connection to rehearse the whole loop without hardware."""

import warnings
from typing import Any

from snac_gym.real.connections import (
    EMERGENCY_STOP,
    NORMAL,
    PROTECTIVE_STOP,
    ArmConnection,
    ConnectionFailure,
    DryRunConnection,
    SimulatedConnection,
    URRTDEConnection,
)
from snac_gym.real.env import RealUREnv
from snac_gym.real.safety import SafetyLayer, SafetyLimits

#: The connections' former names (``*Backend``): still importable from here, with a ``DeprecationWarning``.
_RENAMED = {
    "ArmBackend": ArmConnection,
    "DryRunBackend": DryRunConnection,
    "SimulatedBackend": SimulatedConnection,
    "URRTDEBackend": URRTDEConnection,
}


def __getattr__(name: str) -> Any:
    if name in _RENAMED:
        new = _RENAMED[name].__name__
        warnings.warn(f"snac_gym.real.{name} is deprecated; use snac_gym.real.{new}", DeprecationWarning, stacklevel=2)
        return _RENAMED[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "EMERGENCY_STOP",
    "NORMAL",
    "PROTECTIVE_STOP",
    "ArmConnection",
    "ConnectionFailure",
    "DryRunConnection",
    "RealUREnv",
    "SafetyLayer",
    "SafetyLimits",
    "SimulatedConnection",
    "URRTDEConnection",
]
