"""Sample spaces of the two tasks: random seed poses, targets and feasible ellipses.

Used by the envs' ``reset`` (random episodes) and by the evaluator (random sample sets),
so both draw from the same documented space. Everything is drawn from a NumPy
``Generator``: the same seed gives the same samples on any machine.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from snac_gym.common.validation import real_array, real_number, whole_number
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.robots import ROBOTS
from snac_gym.references import MAX_REFERENCE_SPEED, MIN_ANGULAR_SPEED, MIN_SEMI_AXIS, Ellipse, FixedTarget

#: Where samples come from (:class:`SampleSpace` ``region``).
REGIONS = ("cuboid", "workspace")
#: Default sample cuboid for the UR10, base frame, metres: a box in front of the arm
#: (negative x, as in the paper's numbers) that holds the paper's start point, target
#: and circle, with every corner reachable with margin (tests/test_references_sampling.py).
UR10_CUBOID_LOW = (-0.95, -0.40, 0.20)
UR10_CUBOID_HIGH = (-0.40, 0.70, 0.65)
#: Fewest ``ellipse_points``: four points a quarter turn apart are the fewest that test both axes of an ellipse.
MIN_ELLIPSE_POINTS = 4
#: Most ``ellipse_points`` (each is an IK solve when an ellipse is drawn).
MAX_ELLIPSE_POINTS = 100_000
_UR10_REACH = 1.211738  # |f(0)| of the UR10 in its base frame (outstretched arm), m


@dataclass(frozen=True)
class SampleSpace:
    """Where random episodes come from.

    Attributes:
        low, high: Corners of the task-space cuboid (m, base frame) holding targets,
            ellipses and the seed poses' end effector.
        min_singular_value: Smallest singular value of J (m/rad) allowed at a seed pose
            and along an ellipse, to stay away from singularities.
        joint_margin: Distance (rad) kept from every joint limit.
        semi_axis_range: Range of ellipse semi-axes, m.
        speed_range: Range of |ω|, rad/s (sign drawn at random).
        ellipse_points: How many points around an ellipse are checked for reachability.
        region: ``"cuboid"``: end effectors, targets and ellipses in the cuboid, seed poses on the
            elbow-up branch of the paper's θ0 (Table I's space); ``"workspace"``: seed poses and
            targets from configurations drawn uniformly within the joint limits (less the margin),
            so anywhere the arm reaches in the box, on every branch (:meth:`workspace`).

    Every field is checked when the space is built, not at the first ``reset`` that uses it:
    ``low``/``high`` three finite numbers with low < high; ``min_singular_value`` and ``joint_margin``
    (at most π) finite and ≥ 0; ``semi_axis_range`` and ``speed_range`` two finite numbers, low ≤ high,
    from the smallest ellipse and speed an :class:`~snac_gym.references.Ellipse` takes, with the fastest
    point speed ω·a at most :data:`~snac_gym.references.MAX_REFERENCE_SPEED`; ``ellipse_points`` a whole
    number in [:data:`MIN_ELLIPSE_POINTS`, :data:`MAX_ELLIPSE_POINTS`]; ``region`` one of :data:`REGIONS`.

    Raises:
        ValueError: Naming the field, what it must be and what it got.
    """

    low: tuple[float, float, float] = UR10_CUBOID_LOW
    high: tuple[float, float, float] = UR10_CUBOID_HIGH
    min_singular_value: float = 0.05
    joint_margin: float = 0.2
    semi_axis_range: tuple[float, float] = (0.05, 0.2)
    speed_range: tuple[float, float] = (0.05, 0.3)
    ellipse_points: int = 32
    region: str = "cuboid"

    def __post_init__(self) -> None:
        low, high = real_array("low", self.low, (3,)), real_array("high", self.high, (3,))
        if np.any(low >= high):
            raise ValueError(f"sample cuboid needs low < high on every axis, got low={self.low}, high={self.high}")
        real_number("min_singular_value (m/rad)", self.min_singular_value, 0.0)
        real_number("joint_margin (rad)", self.joint_margin, 0.0, float(np.pi))
        axes = _ordered_pair("semi_axis_range (m)", self.semi_axis_range, MIN_SEMI_AXIS)
        speeds = _ordered_pair("speed_range (rad/s)", self.speed_range, MIN_ANGULAR_SPEED)
        if axes[1] * speeds[1] > MAX_REFERENCE_SPEED:
            raise ValueError(
                "speed_range and semi_axis_range allow an ellipse point speed of "
                f"{axes[1] * speeds[1]:.3g} m/s; at most "
                f"{MAX_REFERENCE_SPEED:g} m/s can be followed, got speed_range={self.speed_range}, "
                f"semi_axis_range={self.semi_axis_range}"
            )
        whole_number("ellipse_points", self.ellipse_points, MIN_ELLIPSE_POINTS, MAX_ELLIPSE_POINTS)
        if not isinstance(self.region, str) or self.region not in REGIONS:
            raise ValueError(f"region must be one of {REGIONS}, got {self.region!r}")

    @classmethod
    def workspace(cls, kinematics: Kinematics, **overrides: object) -> "SampleSpace":
        """The arm's whole reach above its mounting plane: the box |x|, |y| ≤ r, 0 ≤ z ≤ r (r = |f(0)| + 5 %,
        the outstretched arm), configurations drawn within the joint limits, ellipses up to 0.4 rad/s."""
        reach = 1.05 * float(np.linalg.norm(kinematics.forward(np.zeros(kinematics.n_joints))))
        params: dict[str, object] = {
            "low": (-reach, -reach, 0.0), "high": (reach, reach, reach), "speed_range": (0.05, 0.4),
            "region": "workspace",
        }  # fmt: skip
        params.update(overrides)
        return cls(**params)  # type: ignore[arg-type]

    @classmethod
    def for_robot(cls, kinematics: Kinematics, **overrides: object) -> "SampleSpace":
        """The robot's registered cuboid, else the UR10 cuboid scaled by its reach (UR3 and UR5 get a fitting box)."""
        robot = ROBOTS.get(kinematics.robot.lower())
        if robot is not None and robot.cuboid_low is not None:
            params: dict[str, object] = {"low": robot.cuboid_low, "high": robot.cuboid_high}
        else:
            scale = reach_scale(kinematics)
            params = {
                "low": tuple(float(v) * scale for v in UR10_CUBOID_LOW),
                "high": tuple(float(v) * scale for v in UR10_CUBOID_HIGH),
            }
        params.update(overrides)
        return cls(**params)  # type: ignore[arg-type]

    @cached_property
    def _corners(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.low, float), np.asarray(self.high, float)

    def contains(self, point: np.ndarray, tol: float = 1e-9) -> bool:
        """Whether ``point`` ``(3,)``, or every row of ``(N, 3)`` points, lies in the cuboid (within ``tol``)."""
        point = np.asarray(point, float)
        low, high = self._corners
        return bool((point >= low - tol).all() and (point <= high + tol).all())


def reach_scale(kinematics: Kinematics) -> float:
    """The arm's size against the UR10's, for whose reach the paper's numbers are: its outstretched reach |f(0)|
    over the UR10's (1 for the UR10 itself to 6 digits, 0.41 for the UR3, 0.69 for the UR5)."""
    return float(np.linalg.norm(kinematics.forward(np.zeros(kinematics.n_joints))[:3])) / _UR10_REACH


def _ordered_pair(name: str, value: object, smallest: float) -> np.ndarray:
    """``value`` as two finite numbers ``smallest ≤ low ≤ high``, or a ``ValueError`` naming ``name``."""
    pair = real_array(name, value, (2,))
    if not smallest <= pair[0] <= pair[1]:
        raise ValueError(f"{name} must be (low, high) with {smallest:g} <= low <= high, got {value!r}")
    return pair


def nominal_configuration(kinematics: Kinematics) -> np.ndarray:
    """An elbow-up, wrist-down configuration to seed IK: the robot's registered ``nominal_q``
    (the paper's θ0 for the UR arms), else the zero pose clipped to the joint limits."""
    robot = ROBOTS.get(kinematics.robot.lower())
    if robot is not None and robot.nominal_q is not None and len(robot.nominal_q) == kinematics.n_joints:
        return np.array(robot.nominal_q, dtype=float)
    return np.clip(np.zeros(kinematics.n_joints), kinematics.lower_limits, kinematics.upper_limits)


def _well_conditioned(kinematics: Kinematics, q: np.ndarray, space: SampleSpace) -> bool:
    inside = (q >= kinematics.lower_limits + space.joint_margin).all() and (
        q <= kinematics.upper_limits - space.joint_margin
    ).all()
    return bool(inside) and kinematics.singular_values(q)[-1] >= space.min_singular_value


def solve_reachable(
    kinematics: Kinematics, point: np.ndarray, q_init: np.ndarray | None = None, tol: float = 1e-6
) -> np.ndarray | None:
    """A configuration reaching ``point`` (within ``tol``), or ``None`` if IK finds none.

    Tries ``q_init`` (default: the nominal configuration) and then a few fixed variants,
    so the answer is deterministic.
    """
    nominal = nominal_configuration(kinematics)
    starts = [nominal if q_init is None else np.asarray(q_init, float)]
    starts += [nominal + shift for shift in (0.5, -0.5)] + [np.zeros(kinematics.n_joints)]
    for start in starts:
        q, ok = kinematics.inverse_position(point, start, tol=tol)
        if ok:
            return q
    return None


def check_reachable(kinematics: Kinematics, points: np.ndarray, what: str) -> None:
    """Raise ``ValueError`` naming the first of ``points`` that no joint configuration reaches."""
    q_prev = None
    for point in np.atleast_2d(points):
        q_prev = solve_reachable(kinematics, point, q_prev)
        if q_prev is None:
            raise ValueError(
                f"{what}: point {np.round(point, 4).tolist()} m is outside the reachable workspace of "
                f"{kinematics.robot} (no joint configuration reaches it)"
            )


def sample_seed_pose(kinematics: Kinematics, rng: np.random.Generator, space: SampleSpace) -> np.ndarray:
    """A random configuration whose end effector lies in the cuboid, away from singularities and limits.

    A random point of the cuboid is reached by IK from the nominal configuration
    perturbed by up to ±0.4 rad per joint, so poses vary while staying on the
    elbow-up branch the paper's θ0 is on.
    """
    if space.region == "workspace":
        return _workspace_configuration(kinematics, rng, space)
    nominal = nominal_configuration(kinematics)
    for _ in range(1000):
        point = rng.uniform(space.low, space.high)
        start = nominal + rng.uniform(-0.4, 0.4, size=kinematics.n_joints)
        q, ok = kinematics.inverse_position(point, start, tol=1e-6)
        if ok and _well_conditioned(kinematics, q, space):
            return q
    raise RuntimeError(f"no well-conditioned seed pose found in {space}; widen the cuboid or relax the margins")


def _workspace_configuration(kinematics: Kinematics, rng: np.random.Generator, space: SampleSpace) -> np.ndarray:
    """A configuration drawn uniformly within the joint limits less the margin, well-conditioned, end effector in the
    box.

    Uniform in joint space rather than IK of a point: every branch (elbow up or down, wrist
    flipped, the base turned either way) comes out as often as the limits allow it.
    """
    low, high = kinematics.lower_limits + space.joint_margin, kinematics.upper_limits - space.joint_margin
    for _ in range(10000):
        q = rng.uniform(low, high)
        if kinematics.singular_values(q)[-1] >= space.min_singular_value and space.contains(kinematics.forward(q)):
            return q
    raise RuntimeError(f"no well-conditioned configuration found in {space}")


def sample_target(kinematics: Kinematics, rng: np.random.Generator, space: SampleSpace) -> FixedTarget:
    """A random reachable, well-conditioned target in the cuboid (workspace: the end effector of a random
    configuration)."""
    if space.region == "workspace":
        return FixedTarget(kinematics.forward(_workspace_configuration(kinematics, rng, space)))
    for _ in range(1000):
        point = rng.uniform(space.low, space.high)
        q = solve_reachable(kinematics, point)
        if q is not None and _well_conditioned(kinematics, q, space):
            return FixedTarget(point)
    raise RuntimeError(f"no reachable target found in {space}")


def ellipse_is_feasible(kinematics: Kinematics, ellipse: Ellipse, space: SampleSpace) -> bool:
    """Whether every checked point of ``ellipse`` lies in the cuboid and is reached well-conditioned."""
    points = ellipse.points(space.ellipse_points)
    if not space.contains(points):
        return False
    q = solve_reachable(kinematics, points[0])
    if q is None or not _well_conditioned(kinematics, q, space):
        return False
    for point in points[1:]:
        q, ok = kinematics.inverse_position(point, q, tol=1e-6)
        if not ok or not _well_conditioned(kinematics, q, space):
            return False
    return True


def sample_ellipse(kinematics: Kinematics, rng: np.random.Generator, space: SampleSpace) -> Ellipse:
    """A random ellipse (centre, semi-axes, plane orientation, speed, phase) that is wholly feasible."""
    for _ in range(2000):
        speed = rng.uniform(*space.speed_range) * rng.choice((-1.0, 1.0))
        centre = (
            kinematics.forward(_workspace_configuration(kinematics, rng, space))
            if space.region == "workspace"
            else rng.uniform(space.low, space.high)
        )
        ellipse = Ellipse(
            centre=centre,
            semi_axes=rng.uniform(*space.semi_axis_range, size=2),
            orientation=rng.uniform(-np.pi, np.pi, size=3),
            angular_speed=float(speed),
            phase=float(rng.uniform(0.0, 2 * np.pi)),
        )
        if ellipse_is_feasible(kinematics, ellipse, space):
            return ellipse
    raise RuntimeError(f"no feasible ellipse found in {space}; widen the cuboid or shrink the semi-axes")
