"""Damped-least-squares (Levenberg–Marquardt) resolved-rate control, the textbook reference.

References:
    C. W. Wampler, "Manipulator inverse kinematic solutions based on vector formulations and
    damped least-squares methods", IEEE Trans. SMC 16(1):93–101, 1986; Y. Nakamura and
    H. Hanafusa, "Inverse kinematic solutions with singularity robustness for robot
    manipulator control", J. Dyn. Syst. Meas. Control 108(3):163–171, 1986.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from snac_gym.baselines._common import ResolvedRatePolicy, positive_float

from snac_gym.model.kinematics import damped_resolve_rows


class DLSPolicy(ResolvedRatePolicy):
    """Damped-least-squares closed-loop IK.

    Implements, at every control step,

        v = ẋ_d + K (x_d − x)
        u = sat(Jᵀ (J Jᵀ + λ² I)⁻¹ v)

    i.e. the minimiser of ``‖J u − v‖² + λ²‖u‖²``, with ``sat`` the uniform scaling into the
    joint-velocity limits (:func:`snac_gym.baselines._common.scale_into_box`). As λ → 0 this is the
    pseudo-inverse ``J⁺ v``; in singular-value form each direction gets ``σ/(σ² + λ²)``
    instead of ``1/σ``, at most ``1/(2λ)``. The n×n system (n = 3) is solved directly,
    never inverted.

    Args:
        env: The env (or policy context) to drive.
        gain: Task-space feedback gain ``K``, 1/s; the effort knob (``effort_parameter``).
        damping: Damping factor ``λ``, m/rad.
        joint_limits: Clamp into the position-limit box Ω(θ) (:class:`~snac_gym.baselines._common.ResolvedRatePolicy`).

    Raises:
        ValueError: If ``gain`` or ``damping`` is not positive.
    """

    def __init__(self, env: Any, gain: float = 2.0, damping: float = 0.01, joint_limits: bool | None = None) -> None:
        super().__init__(env, gain, joint_limits)
        self.damping = positive_float("damping", damping)

    def resolve(self, jacobian: np.ndarray, task_velocity: np.ndarray) -> np.ndarray:
        """``Jᵀ (J Jᵀ + λ² I)⁻¹ v`` for one ``(J, v)`` ``(n, m)``, ``(n,)``, or for stacks ``(B, n, m)``, ``(B, n)`` in
        one compiled pass (:func:`~snac_gym.model.kinematics.damped_resolve_rows`: a row alone is bit for bit that
        row of a stack)."""
        return damped_resolve_rows(jacobian, task_velocity, self.damping)

    #: :meth:`resolve` of each row: it takes the stacks as they come.
    resolve_batch = resolve
