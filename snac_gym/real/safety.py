"""The safety layer of the real-robot env, enforced whatever the policy does.

Two kinds of rule:

* **Shaping** (every command): clip to ``speed_scale`` × the URDF velocity limits, then bound the
  change from the previous command by ``max_joint_acceleration`` × dt.
* **Stopping** (the arm is stopped and the episode ends): the end effector leaves the task box,
  a joint comes within ``joint_limit_margin`` of its limit, the loop misses its deadline for
  ``max_missed_deadlines`` periods running, or the controller reports a protective or
  emergency stop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snac_gym.kinematics import Kinematics
from snac_gym.sampling import UR10_CUBOID_HIGH, UR10_CUBOID_LOW

_BOX_MARGIN = 0.15  # m around the sample cuboid: room for overshoot, not for the table


@dataclass(frozen=True)
class SafetyLimits:
    """Conservative defaults for a first run next to a real arm.

    Attributes:
        speed_scale: Fraction of the URDF joint-velocity limits the command may use (0.25: the
            UR10 base joints at most 0.54 rad/s).
        max_joint_acceleration: Bound on |u_k − u_{k−1}| / dt, rad/s².
        box_low, box_high: Task-space box (m, base frame) the end effector must stay in;
            default: the sample cuboid grown by 0.15 m.
        joint_limit_margin: Distance (rad) from the URDF joint limits that stops the arm.
        max_missed_deadlines: Consecutive late periods that stop the arm.
        deadline_slack: A period counts as late when it lasts over (1 + slack) × dt.
    """

    speed_scale: float = 0.25
    max_joint_acceleration: float = 2.0
    box_low: tuple[float, float, float] = tuple(v - _BOX_MARGIN for v in UR10_CUBOID_LOW)  # type: ignore[assignment]
    box_high: tuple[float, float, float] = tuple(v + _BOX_MARGIN for v in UR10_CUBOID_HIGH)  # type: ignore[assignment]
    joint_limit_margin: float = 0.1
    max_missed_deadlines: int = 3
    deadline_slack: float = 0.5

    def __post_init__(self) -> None:
        if not 0 < self.speed_scale <= 1:
            raise ValueError(f"speed_scale must be in (0, 1], got {self.speed_scale}")
        if not self.max_joint_acceleration > 0:
            raise ValueError(f"max_joint_acceleration must be positive, got {self.max_joint_acceleration}")
        if np.any(np.asarray(self.box_low) >= np.asarray(self.box_high)):
            raise ValueError(f"task box needs low < high, got {self.box_low} and {self.box_high}")
        if self.max_missed_deadlines < 1:
            raise ValueError(f"max_missed_deadlines must be at least 1, got {self.max_missed_deadlines}")


class SafetyLayer:
    """Applies :class:`SafetyLimits` for one arm and keeps the deadline count.

    Args:
        kinematics: The shared kinematics (limits, and x for the box check).
        limits: The rules' parameters.
        dt: Control period, s.
    """

    def __init__(self, kinematics: Kinematics, limits: SafetyLimits, dt: float) -> None:
        self.kinematics = kinematics
        self.limits = limits
        self.dt = dt
        self.speed_bound = limits.speed_scale * kinematics.velocity_limits
        self.step_bound = limits.max_joint_acceleration * dt
        self._box_low = np.asarray(limits.box_low, dtype=float)
        self._box_high = np.asarray(limits.box_high, dtype=float)
        self._late_periods = 0

    def reset(self) -> None:
        self._late_periods = 0

    def shape(self, command: np.ndarray, previous: np.ndarray) -> np.ndarray:
        """The command actually sent: speed-clipped, then rate-limited from ``previous``."""
        clipped = np.clip(command, -self.speed_bound, self.speed_bound)
        return np.clip(clipped, previous - self.step_bound, previous + self.step_bound)

    def violation(self, q: np.ndarray, x: np.ndarray) -> str | None:
        """The first stopping rule the state breaks, as a short message, or ``None``."""
        low = self.kinematics.lower_limits + self.limits.joint_limit_margin
        high = self.kinematics.upper_limits - self.limits.joint_limit_margin
        outside = np.flatnonzero((q < low) | (q > high))
        if outside.size:
            j = int(outside[0])
            return (
                f"joint {j} ({self.kinematics.joint_names[j]}) at {q[j]:.3f} rad is within "
                f"{self.limits.joint_limit_margin} rad of its limit"
            )
        if np.any(x < self._box_low) or np.any(x > self._box_high):
            return f"end effector {np.round(x, 3).tolist()} m left the task box {self.limits.box_low}–{self.limits.box_high}"
        return None

    def record_period(self, duration: float) -> str | None:
        """Count late periods; a message once ``max_missed_deadlines`` come in a row."""
        if duration > (1.0 + self.limits.deadline_slack) * self.dt:
            self._late_periods += 1
        else:
            self._late_periods = 0
        if self._late_periods >= self.limits.max_missed_deadlines:
            return f"control loop missed its {self.dt * 1e3:.1f} ms deadline {self._late_periods} periods running"
        return None
