"""The exact kinematic engine: the paper's model θₖ₊₁ = θₖ + uₖΔt (eq. 3), thousands of times faster than a
simulator."""

from __future__ import annotations

import math

import numpy as np

from snac_gym.model.kinematics import Kinematics, joint_step
from snac_gym.physics.base import MAX_DT


class KinematicArm:
    """The paper's kinematic model, integrated exactly: θₖ₊₁ = θₖ + uₖΔt, θ̇ = the held command.

    This is what the evaluator's kinematic engine steps (:func:`snac_gym.rollout.simulate_kinematic`):
    the measured joint velocity is the command held over the previous period (zero at the
    start); joint position limits are not enforced, as in the paper's model.
    """

    def __init__(self, kinematics: Kinematics, dt: float) -> None:
        if not (math.isfinite(dt) and 0 < dt <= MAX_DT):
            raise ValueError(f"dt must be positive, finite and at most {MAX_DT:g} s, got {dt}")
        self.dt = float(dt)
        self._q = np.zeros(kinematics.n_joints)
        self._qdot = np.zeros(kinematics.n_joints)

    def reset(self, q0: np.ndarray) -> None:
        self._q = np.array(q0, dtype=float)
        self._qdot = np.zeros_like(self._q)

    def apply(self, u: np.ndarray) -> None:
        self._q = joint_step(self._q, u, self.dt)
        self._qdot = np.array(u, dtype=float)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self._q.copy(), self._qdot.copy()

    def restore(self, q: np.ndarray, qdot: np.ndarray, command: np.ndarray) -> None:
        self._q, self._qdot = np.array(q, dtype=float), np.array(qdot, dtype=float)

    def close(self) -> None:
        pass
