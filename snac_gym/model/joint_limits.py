"""Joint position limits at the velocity level: the box Ω(θ) of admissible joint speeds.

The paper's model θ̇ = u (eq. 3) has velocity limits only. A redundant arm (7 joints for a 3-D
task) has self-motion that no task error sees, so its joints can drift onto their position
limits, and the Panda's are tight (joint 4 in [−3.07, −0.07] rad). Li, Zhang and Jin (2017),
the RNN baseline, fold θ⁻ ≤ θ ≤ θ⁺ into the network's constraint set as a box on u that
depends on θ:

    Ω(θ) = {u : η⁻(θ) ≤ u ≤ η⁺(θ)},
    η⁻(θ) = max(−ū, κ(θ⁻ + δ − θ)),   η⁺(θ) = min(ū, κ(θ⁺ − δ − θ))

(ū the velocity limits, κ > 0 a gain, δ ≥ 0 a margin). With the exact update
θₖ₊₁ = θₖ + uₖΔt and κΔt ≤ 1, a joint inside [θ⁻ + δ, θ⁺ − δ] never leaves it: its distance to
a bound shrinks by at most the factor (1 − κΔt) per step. Far from the limits (more than
ū/κ + δ) the box is the velocity box itself, bit for bit.

The RNN projects onto Ω(θ) inside its network (P_Ω), so the other joints take over the task
motion a clamped joint cannot make. The controllers without a mechanism of their own (SVF,
DLS, LQR, SNAC) get the documented one here: their command, already inside the velocity
limits, is clamped into Ω(θ) component-wise (:meth:`JointLimitBox.clamp`). Both are on by
default on the 7-DOF arms only (:func:`limits_by_default`), so the 6-DOF runs are unchanged.
"""

from __future__ import annotations

import numpy as np

from snac_gym.model.kinematics import Kinematics

#: κ, 1/s: Ω(θ) starts to narrow ū/κ + δ from a limit (0.2-0.3 rad for the 7-DOF arms).
POSITION_LIMIT_GAIN = 10.0
#: δ, rad: the distance kept from every position limit.
POSITION_LIMIT_MARGIN = 0.05
#: Dimension of a full end-effector pose: an arm with more joints is redundant for every task.
POSE_DIM = 6


def limits_by_default(kinematics: Kinematics) -> bool:
    """Whether a controller guards the position limits by default: on arms redundant for the full
    pose (m > :data:`POSE_DIM`, the 7-DOF arms) whose kinematics has position limits (a stand-in
    kinematics in a test may have none). The 6-DOF UR arms, the paper's, run as before bit for bit
    (their joints turn ±2π, except the elbow's ±π); ``joint_limits=True`` guards them too."""
    has_limits = hasattr(kinematics, "lower_limits") and hasattr(kinematics, "upper_limits")
    return has_limits and kinematics.n_joints > POSE_DIM


class JointLimitBox:
    """The box Ω(θ) of joint speeds that keep θ inside its position limits (module docs).

    Args:
        kinematics: Gives θ⁻ and θ⁺ (the URDF's).
        velocity_limits: ū, rad/s, shape ``(m,)``.
        dt: Control period, s (κΔt ≤ 1 is checked).
        gain: κ, 1/s.
        margin: δ, rad.

    Raises:
        ValueError: If κΔt > 1, κ ≤ 0, δ < 0 or the margins leave no room between the limits.
    """

    def __init__(
        self,
        kinematics: Kinematics,
        velocity_limits: np.ndarray,
        dt: float,
        gain: float = POSITION_LIMIT_GAIN,
        margin: float = POSITION_LIMIT_MARGIN,
    ) -> None:
        if not (gain > 0 and gain * dt <= 1.0):
            raise ValueError(f"the position-limit gain κ must satisfy 0 < κΔt ≤ 1, got κ={gain}, Δt={dt}")
        if not margin >= 0 or np.any(kinematics.upper_limits - kinematics.lower_limits <= 2 * margin):
            raise ValueError(f"margin {margin} rad leaves no room between the joint limits")
        self.gain, self.margin = float(gain), float(margin)
        self.velocity_limits = np.asarray(velocity_limits, dtype=float)
        self._inner_lower = kinematics.lower_limits + margin
        self._inner_upper = kinematics.upper_limits - margin

    def bounds(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(η⁻(θ), η⁺(θ))`` for θ ``(m,)`` or a batch ``(B, m)``; η⁻ ≤ η⁺ always (a joint
        outside its inner range is driven back at no more than ū)."""
        limits = self.velocity_limits
        lower = np.minimum(np.maximum(self.gain * (self._inner_lower - q), -limits), limits)
        upper = np.maximum(np.minimum(self.gain * (self._inner_upper - q), limits), -limits)
        return lower, upper

    def clamp(self, q: np.ndarray, command: np.ndarray) -> np.ndarray:
        """``command`` clamped into Ω(θ) component-wise (one command or a batch, a new array)."""
        lower, upper = self.bounds(q)
        clamped: np.ndarray = np.minimum(np.maximum(command, lower), upper)
        return clamped


def make_limit_box(policy: object, enabled: bool | None) -> JointLimitBox | None:
    """The policy's :class:`JointLimitBox`, or ``None`` when off (``enabled=None``: :func:`limits_by_default`).

    ``policy`` has the :class:`~snac_gym.policies.base.BasePolicy` attributes ``kinematics``,
    ``velocity_limits`` and ``dt``.
    """
    kinematics = policy.kinematics  # type: ignore[attr-defined]
    if not (limits_by_default(kinematics) if enabled is None else enabled):
        return None
    return JointLimitBox(kinematics, policy.velocity_limits, policy.dt)  # type: ignore[attr-defined]


def joint_limit_margins(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Each trajectory's closest approach to a position limit, rad: ``min over k, j of
    min(θₖⱼ − θ⁻ⱼ, θ⁺ⱼ − θₖⱼ)`` for θ ``(B, K, m)``; negative where a limit was crossed."""
    return joint_limit_margins_of_extremes(q.min(axis=1), q.max(axis=1), lower, upper)


def joint_limit_margins_of_extremes(
    q_min: np.ndarray, q_max: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> np.ndarray:
    """:func:`joint_limit_margins` from each trajectory's smallest and largest θⱼ over k, ``(B, m)`` each.

    The same number bit for bit: rounding is monotone, so ``min_k(θₖⱼ − θ⁻ⱼ) = (min_k θₖⱼ) − θ⁻ⱼ``
    exactly, and two reductions replace four passes over the ``(B, K, m)`` array.
    """
    margins: np.ndarray = np.minimum(q_min - lower, upper - q_max).min(axis=1)
    return margins
