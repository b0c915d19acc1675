"""The safety layer of the real-robot env, enforced whatever the policy does.

Two kinds of rule:

* **Shaping** (every command): clip to ``speed_scale`` × the joint speed limits (the URDF's, and on a UR
  arm no more than its datasheet's: :func:`snac_gym.model.ur_models.velocity_limits`), then bound the
  change from the previous command by ``max_joint_acceleration`` × dt.
* **Stopping** (the arm is stopped and the episode ends):

  - the controller's joint state is not finite, or stale (its timestamp did not advance for
    ``max_stale_periods`` periods running);
  - the end effector leaves the task box, or a joint comes within ``joint_limit_margin`` of its
    limit;
  - the loop is late too often (``max_missed_deadlines`` late periods within the last
    ``deadline_window``), or once by a lot (a period longer than ``max_period``): the deadline
    stop, which ``deadline_stop=False`` turns into a count only (a rehearsal: a simulated arm or a
    dry run has nothing for a late loop to harm);
  - the controller reports a protective or emergency stop (checked by the env);
  - the TCP position the controller reports differs from the model's f(θ) by more than
    ``max_tcp_mismatch`` (a wrong tool, base frame or arm model), where the connection reports one.

Every limit is checked when :class:`SafetyLimits` is built: a NaN or infinite limit would switch
its rule off without a word (comparisons with NaN are false), so it is refused instead.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from snac_gym.model.kinematics import Kinematics
from snac_gym.model.ur_models import velocity_limits
from snac_gym.sampling import SampleSpace

_BOX_MARGIN = 0.15  # m around the sample cuboid: room for overshoot, not for the table


def check_finite_in(name: str, value: float, low: float, high: float, low_open: bool = False) -> None:
    """Refuse a non-finite ``value`` or one outside ``[low, high]`` (``(low, high]`` with ``low_open``)."""
    below = value <= low if low_open else value < low
    if not math.isfinite(value) or below or value > high:
        bracket = "(" if low_open else "["
        raise ValueError(f"{name} must be a finite number in {bracket}{low:g}, {high:g}], got {value!r}")


def check_whole_in(name: str, value: int, low: int, high: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
        raise ValueError(f"{name} must be a whole number in [{low}, {high}], got {value!r}")


@dataclass(frozen=True)
class SafetyLimits:
    """Conservative defaults for a first run next to a real arm.

    Attributes:
        speed_scale: Fraction of the joint speed limits the command may use (the URDF's, and on a UR arm
            no more than the datasheet's; 0.25: the UR10 base joints at most 0.52 rad/s), in (0, 1].
        max_joint_acceleration: Bound on |u_k − u_{k−1}| / dt, rad/s², in (0, 40] (the UR
            controllers' own joint acceleration limit is 40 rad/s²).
        box_low, box_high: Task-space box (m, base frame) the end effector must stay in; finite,
            low < high; both or neither (``None``: the arm's sample cuboid grown by 0.15 m,
            :meth:`task_box`).
        joint_limit_margin: Distance (rad) from the URDF joint limits that stops the arm, in
            [0, π/2].
        max_missed_deadlines: Late periods within the last ``deadline_window`` that stop the arm.
        deadline_window: Periods over which late ones are counted (1: only consecutive ones).
        deadline_slack: A period counts as late when it lasts over (1 + slack) × dt; in [0, 10].
        max_period: A single period longer than this (s) stops the arm at once, however rare: a
            stall of the host. Default 40 ms, five periods at 125 Hz (the controller watchdog's
            own default in :class:`~snac_gym.real.connections.URRTDEConnection`).
        max_stale_periods: Periods running in which the controller's state timestamp may fail to
            advance before the state counts as stale.
        rest_speed: Joint speed (rad/s) under which the arm counts as at rest after a stop.
        max_tcp_mismatch: Largest distance (m) between the controller's reported TCP position
            and the model's forward kinematics f(θ) of the same state, in (0, 1].
        deadline_stop: Whether the deadline rules (``max_missed_deadlines``, ``max_period``) stop the
            arm; ``False``: late periods are counted (``RealUREnv.timing()``) but stop nothing, for a
            rehearsal on a simulated arm or a dry run (``snac-gym real`` turns it off there, and refuses to on a real
            arm).
    """

    speed_scale: float = 0.25
    max_joint_acceleration: float = 2.0
    box_low: tuple[float, float, float] | None = None
    box_high: tuple[float, float, float] | None = None
    joint_limit_margin: float = 0.1
    max_missed_deadlines: int = 3
    deadline_window: int = 25
    deadline_slack: float = 0.5
    max_period: float = 0.04
    max_stale_periods: int = 3
    rest_speed: float = 0.01
    max_tcp_mismatch: float = 0.005
    deadline_stop: bool = True

    def __post_init__(self) -> None:
        check_finite_in("speed_scale", self.speed_scale, 0.0, 1.0, low_open=True)
        check_finite_in("max_joint_acceleration", self.max_joint_acceleration, 0.0, 40.0, low_open=True)
        check_finite_in("joint_limit_margin", self.joint_limit_margin, 0.0, math.pi / 2)
        check_finite_in("deadline_slack", self.deadline_slack, 0.0, 10.0)
        check_finite_in("max_period", self.max_period, 0.0, 10.0, low_open=True)
        check_finite_in("rest_speed", self.rest_speed, 0.0, 1.0, low_open=True)
        check_finite_in("max_tcp_mismatch", self.max_tcp_mismatch, 0.0, 1.0, low_open=True)
        check_whole_in("deadline_window", self.deadline_window, 1, 100_000)
        check_whole_in("max_missed_deadlines", self.max_missed_deadlines, 1, self.deadline_window)
        check_whole_in("max_stale_periods", self.max_stale_periods, 1, 1000)
        if not isinstance(self.deadline_stop, (bool, np.bool_)):
            raise ValueError(f"deadline_stop must be True or False, got {self.deadline_stop!r}")
        if (self.box_low is None) != (self.box_high is None):
            raise ValueError(f"give both corners of the task box or neither, got {self.box_low} and {self.box_high}")
        if self.box_low is None:
            return
        low, high = np.asarray(self.box_low, dtype=float), np.asarray(self.box_high, dtype=float)
        if low.shape != (3,) or high.shape != (3,):
            raise ValueError(f"task box corners must be 3 numbers each (m), got {self.box_low} and {self.box_high}")
        if not (np.isfinite(low).all() and np.isfinite(high).all()):
            raise ValueError(f"task box corners must be finite (m), got {self.box_low} and {self.box_high}")
        if np.any(low >= high):
            raise ValueError(f"task box needs low < high, got {self.box_low} and {self.box_high}")

    def task_box(self, kinematics: Kinematics) -> tuple[np.ndarray, np.ndarray]:
        """The task box's corners (m, base frame): the given ones, or the arm's sample cuboid
        (:meth:`~snac_gym.sampling.SampleSpace.for_robot`: the UR10's, scaled by the arm's reach) grown by 0.15 m."""
        if self.box_low is not None:
            return np.asarray(self.box_low, dtype=float), np.asarray(self.box_high, dtype=float)
        space = SampleSpace.for_robot(kinematics)
        return np.asarray(space.low, dtype=float) - _BOX_MARGIN, np.asarray(space.high, dtype=float) + _BOX_MARGIN


class SafetyLayer:
    """Applies :class:`SafetyLimits` for one arm and keeps the deadline and staleness counts.

    Args:
        kinematics: The shared kinematics (limits, and x for the box check).
        limits: The rules' parameters.
        dt: Control period, s.
    """

    def __init__(self, kinematics: Kinematics, limits: SafetyLimits, dt: float) -> None:
        self.kinematics = kinematics
        self.limits = limits
        self.dt = dt
        self.speed_bound = limits.speed_scale * velocity_limits(kinematics.robot, kinematics.velocity_limits)
        self.step_bound = limits.max_joint_acceleration * dt
        self._box_low, self._box_high = limits.task_box(kinematics)
        self._joint_low = kinematics.lower_limits + limits.joint_limit_margin
        self._joint_high = kinematics.upper_limits - limits.joint_limit_margin
        self._late_flags: deque[bool] = deque(maxlen=limits.deadline_window)
        self._last_timestamp = -math.inf
        self._stale_reads = 0

    def reset(self) -> None:
        self._late_flags.clear()
        self._last_timestamp = -math.inf
        self._stale_reads = 0

    def shape(self, command: np.ndarray, previous: np.ndarray) -> np.ndarray:
        """The command actually sent: speed-clipped, then rate-limited from ``previous``."""
        clipped = np.clip(command, -self.speed_bound, self.speed_bound)
        return np.clip(clipped, previous - self.step_bound, previous + self.step_bound)

    def pose_violation(self, q: np.ndarray, x: np.ndarray) -> str | None:
        """The first position rule (finite, joint margin, task box) ``q``/``x`` break, or ``None``."""
        if not (np.isfinite(q).all() and np.isfinite(x).all()):
            return f"non-finite joint state from the controller: q = {np.asarray(q).tolist()}"
        outside = np.flatnonzero((q < self._joint_low) | (q > self._joint_high))
        if outside.size:
            j = int(outside[0])
            return (
                f"joint {j} ({self.kinematics.joint_names[j]}) at {q[j]:.3f} rad is within "
                f"{self.limits.joint_limit_margin} rad of its limit"
            )
        if np.any(x < self._box_low) or np.any(x > self._box_high):
            return (
                f"end effector {np.round(x, 3).tolist()} m left the task box "
                f"{self.limits.box_low}–{self.limits.box_high}"
            )
        return None

    def violation(self, q: np.ndarray, qdot: np.ndarray, x: np.ndarray, timestamp: float) -> str | None:
        """The first stopping rule the measured state breaks, as a short message, or ``None``.

        Args:
            q, qdot: Measured joint positions (rad) and velocities (rad/s).
            x: End-effector position f(q), m.
            timestamp: The controller's time stamp of this state, s.
        """
        if not np.isfinite(qdot).all():
            return f"non-finite joint velocities from the controller: qdot = {np.asarray(qdot).tolist()}"
        if not math.isfinite(timestamp):
            return f"non-finite state timestamp from the controller: {timestamp!r}"
        if timestamp > self._last_timestamp:
            self._last_timestamp, self._stale_reads = timestamp, 0
        else:
            self._stale_reads += 1
            if self._stale_reads >= self.limits.max_stale_periods:
                return (
                    f"stale joint state: the controller's timestamp stayed at {timestamp:.6f} s "
                    f"for {self._stale_reads} periods running"
                )
        return self.pose_violation(q, x)

    def tcp_violation(self, x_model: np.ndarray, x_reported: np.ndarray) -> str | None:
        """A message when the controller's TCP position and the model's f(θ) differ by over ``max_tcp_mismatch``."""
        gap = float(np.linalg.norm(np.asarray(x_reported, dtype=float) - x_model))
        if not gap <= self.limits.max_tcp_mismatch:  # NaN-safe
            return (
                f"TCP mismatch: the controller reports {np.round(x_reported, 4).tolist()} m, the model's f(q) is "
                f"{np.round(x_model, 4).tolist()} m ({gap * 1e3:.1f} mm apart, limit "
                f"{self.limits.max_tcp_mismatch * 1e3:.1f} mm): check the TCP offset, base frame and arm model"
            )
        return None

    def stall(self, duration: float) -> str | None:
        """A message when ``duration`` (s, a period so far or whole) is over ``max_period`` (and ``deadline_stop``)."""
        if self.limits.deadline_stop and duration > self.limits.max_period:
            return (
                f"control loop stalled: one period took {duration * 1e3:.1f} ms (limit "
                f"{self.limits.max_period * 1e3:.1f} ms)"
            )
        return None

    def record_period(self, duration: float) -> str | None:
        """Count late periods; a message once one is over ``max_period`` or too many are late in the window
        (never without ``deadline_stop``: then they are only counted)."""
        stalled = self.stall(duration)
        if stalled is not None:
            return stalled
        self._late_flags.append(duration > (1.0 + self.limits.deadline_slack) * self.dt)
        late = sum(self._late_flags)
        if self.limits.deadline_stop and late >= self.limits.max_missed_deadlines:
            return (
                f"control loop missed its {self.dt * 1e3:.1f} ms deadline in {late} of the last "
                f"{len(self._late_flags)} periods"
            )
        return None
