"""Task-space references: a fixed target (regulation) and a point on an ellipse (tracking).

Both give ``x_d(t)`` and ``ẋ_d(t)`` in the robot's base frame and a ``centre``: the
target itself, or the ellipse centre. Tracking controllers that need ``φ(0) = 0``
(Section IV, eq. 29) express ``x_d`` relative to this centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

#: The paper's seed pose θ0 (Section V), rad.
PAPER_Q0 = (-0.51, -1.04, 1.48, -1.82, -1.45, -1.62)
#: The paper's regulation target (Section V-B), m, base frame.
PAPER_TARGET = (-0.658, 0.626, 0.407)
#: The paper's tracking circle (Section V-C): centre (m), radius 0.2 m, 0.075 rad/s.
PAPER_CIRCLE_CENTRE = (-0.7, 0.0, 0.5)
PAPER_CIRCLE_RADIUS = 0.2
PAPER_CIRCLE_SPEED = 0.075
#: Smallest semi-axis of an ellipse, m: below it the ellipse is a point within any success
#: tolerance, and tiny axes (1e-300 m) make a degenerate, meaningless reference.
MIN_SEMI_AXIS = 1e-3
#: Slowest angular speed |ω| of an ellipse, rad/s (a lap in 1.7 h): ω = 0 is a fixed point, a
#: regulation task posing as tracking.
MIN_ANGULAR_SPEED = 1e-3
#: Fastest reference point speed |ω|·max(a, b), m/s: about a UR arm's top tool speed. Faster
#: references (ω = 1e6 rad/s gave ẋ_d ≈ 1e5 m/s) cannot be followed by any joint-velocity command.
MAX_REFERENCE_SPEED = 3.0


def _vector(value: Any, size: int, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be {size} numbers, got {value!r}") from exc
    if arr.shape != (size,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be {size} finite numbers, got {value!r}")
    return arr


def rotation_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation matrix ``Rz(yaw) Ry(pitch) Rx(roll)`` (URDF convention)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


_ZERO3 = np.zeros(3)
_ZERO3.setflags(write=False)


@dataclass(frozen=True)
class FixedTarget:
    """Regulation reference: ``x_d(t) = target``, ``ẋ_d(t) = 0`` (Section III)."""

    target: np.ndarray

    if TYPE_CHECKING:  # any 3 numbers are taken (__post_init__ makes the read-only array)

        def __init__(self, target: ArrayLike) -> None: ...

    def __post_init__(self) -> None:
        target = _vector(self.target, 3, "target")
        target.setflags(write=False)  # returned without copying by position(): keep it immutable
        object.__setattr__(self, "target", target)

    @property
    def centre(self) -> np.ndarray:
        return self.target

    def position(self, t: float) -> np.ndarray:
        return self.target

    def velocity(self, t: float) -> np.ndarray:
        return _ZERO3

    def position_and_velocity(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(x_d(t), ẋ_d(t))`` in one call (the env's per-step form)."""
        return self.target, _ZERO3

    def trajectory(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``x_d`` and ``ẋ_d`` at every time of ``times`` ``(K,)``, each of shape ``(K, 3)``."""
        count = len(np.asarray(times))
        return np.tile(self.target, (count, 1)), np.zeros((count, 3))

    def points(self, count: int = 1) -> np.ndarray:
        """Points the reference visits (for reachability checks)."""
        return self.target[None, :].copy()

    def to_dict(self) -> dict[str, Any]:
        return {"target": self.target.tolist()}


@dataclass(frozen=True)
class Ellipse:
    """Tracking reference: a point moving on an ellipse at constant angular rate (Section IV).

    ``x_d(t) = c + R (a cos(ωt + φ) ê₁ + b sin(ωt + φ) ê₂)`` and
    ``ẋ_d(t) = R (−a ω sin(ωt + φ) ê₁ + b ω cos(ωt + φ) ê₂)``, with ``R`` the rotation of the
    ellipse plane given as roll-pitch-yaw. With zero orientation the ellipse lies in the
    horizontal plane z = c_z of the base frame, ``a`` along x and ``b`` along y.

    Dictionary keys (``options={"ellipse": {...}}`` of the tracking env):

    ============== ========= ===========================================================
    key            unit      meaning
    ============== ========= ===========================================================
    centre         m         ``[x, y, z]`` centre in the base frame (required)
    semi_axes      m         ``[a, b]``, each ≥ 1 mm; or ``radius`` for a circle (one required)
    orientation    rad       ``[roll, pitch, yaw]`` of the ellipse plane (default zeros)
    angular_speed  rad/s     ω, 0.001 ≤ |ω|, |ω|·max(a, b) ≤ 3 m/s (default 0.075, the paper's)
    phase          rad       φ, the angle at t = 0 (default 0)
    ============== ========= ===========================================================
    """

    centre: np.ndarray
    semi_axes: np.ndarray
    orientation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_speed: float = PAPER_CIRCLE_SPEED
    phase: float = 0.0

    if TYPE_CHECKING:  # any numbers are taken (__post_init__ makes the arrays); the derived arrays of _bind_arrays
        _packed: np.ndarray = field(init=False, repr=False, compare=False)
        _axes_matrix: np.ndarray = field(init=False, repr=False, compare=False)
        _major: np.ndarray = field(init=False, repr=False, compare=False)
        _minor: np.ndarray = field(init=False, repr=False, compare=False)
        _floats: tuple[float, ...] = field(init=False, repr=False, compare=False)

        def __init__(
            self,
            centre: ArrayLike,
            semi_axes: ArrayLike,
            orientation: ArrayLike = ...,
            angular_speed: float = PAPER_CIRCLE_SPEED,
            phase: float = 0.0,
        ) -> None: ...

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre", _vector(self.centre, 3, "centre"))
        axes = _vector(self.semi_axes, 2, "semi_axes")
        if np.any(axes < MIN_SEMI_AXIS):
            raise ValueError(f"semi_axes must be positive, at least {MIN_SEMI_AXIS:g} m, got {axes.tolist()}")
        object.__setattr__(self, "semi_axes", axes)
        object.__setattr__(self, "orientation", _vector(self.orientation, 3, "orientation"))
        for name in ("angular_speed", "phase"):
            try:
                value = float(getattr(self, name))
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be a number, got {getattr(self, name)!r}") from None
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        speed = abs(self.angular_speed)
        if speed < MIN_ANGULAR_SPEED:
            raise ValueError(
                f"angular_speed must be at least {MIN_ANGULAR_SPEED:g} rad/s in magnitude (0 is a fixed point), "
                f"got {self.angular_speed}"
            )
        if speed * float(axes.max()) > MAX_REFERENCE_SPEED:
            raise ValueError(
                f"the ellipse moves at |ω|·max(a, b) = {speed * float(axes.max()):.3g} m/s; at most "
                f"{MAX_REFERENCE_SPEED:g} m/s can be followed (lower angular_speed or semi_axes)"
            )
        rot = rotation_from_rpy(*self.orientation)
        # Columns scaled by the semi-axes: x_d = c + axes_matrix @ [cos, sin].
        derived = (rot[:, :2] * axes, rot[:, 0] * axes[0], rot[:, 1] * axes[1])  # _axes_matrix, _major, _minor
        _bind_arrays(self, np.concatenate([np.ravel(a) for a in (self.centre, axes, self.orientation, *derived)]))

    def __reduce__(self) -> tuple[Any, ...]:
        # The evaluator sends every sample to a worker at each pass of its knob search: the one array
        # behind the six (see _bind_arrays) pickles and loads 3x faster than they do, and the checks
        # of __post_init__ ran when the ellipse was built.
        return _unpickle_ellipse, (self._packed, self.angular_speed, self.phase)

    @classmethod
    def paper_circle(cls) -> "Ellipse":
        """The paper's circle: radius 0.2 m around [-0.7, 0, 0.5] m at 0.075 rad/s."""
        return cls(PAPER_CIRCLE_CENTRE, (PAPER_CIRCLE_RADIUS, PAPER_CIRCLE_RADIUS))

    def scaled(self, factor: float) -> "Ellipse":
        """The ellipse with its centre and semi-axes ``factor`` times as large (about the base), at the same
        orientation, angular speed and phase."""
        return replace(self, centre=self.centre * factor, semi_axes=self.semi_axes * factor)

    @classmethod
    def from_dict(cls, spec: Mapping[str, Any]) -> "Ellipse":
        """Build from the documented keys; unknown or missing keys raise ``ValueError``."""
        if not isinstance(spec, Mapping):
            raise ValueError(f"ellipse must be a mapping with keys centre, semi_axes|radius, ..., got {spec!r}")
        allowed = {"centre", "semi_axes", "radius", "orientation", "angular_speed", "phase"}
        unknown = set(spec) - allowed
        if unknown:
            raise ValueError(f"unknown ellipse keys {sorted(unknown)}; allowed: {sorted(allowed)}")
        if "centre" not in spec:
            raise ValueError("ellipse needs a 'centre'")
        if ("semi_axes" in spec) == ("radius" in spec):
            raise ValueError("ellipse needs exactly one of 'semi_axes' or 'radius'")
        axes = spec["semi_axes"] if "semi_axes" in spec else (spec["radius"], spec["radius"])
        return cls(
            centre=spec["centre"],
            semi_axes=axes,
            orientation=spec.get("orientation", (0.0, 0.0, 0.0)),
            angular_speed=spec.get("angular_speed", PAPER_CIRCLE_SPEED),
            phase=spec.get("phase", 0.0),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "centre": self.centre.tolist(),
            "semi_axes": self.semi_axes.tolist(),
            "orientation": self.orientation.tolist(),
            "angular_speed": self.angular_speed,
            "phase": self.phase,
        }

    def position(self, t: float) -> np.ndarray:
        return self.position_and_velocity(t)[0]

    def velocity(self, t: float) -> np.ndarray:
        return self.position_and_velocity(t)[1]

    def position_and_velocity(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(x_d(t), ẋ_d(t))`` in one call (the env's per-step form: scalar math, no arrays of angles)."""
        angle = self.angular_speed * t + self.phase
        cos, sin = math.cos(angle), math.sin(angle)
        w = self.angular_speed
        wc, ws = w * cos, w * sin
        # c + cos·major + sin·minor and (ω cos)·minor − (ω sin)·major coordinate by coordinate in Python floats:
        # the products and sums of the 3-vector expression in its order, so its floats, at a third of the cost of
        # six small-array operations (an env step's largest Python share when tracking)
        c0, c1, c2, a0, a1, a2, b0, b1, b2 = self._floats
        return (
            np.array((c0 + cos * a0 + sin * b0, c1 + cos * a1 + sin * b1, c2 + cos * a2 + sin * b2)),
            np.array((wc * b0 - ws * a0, wc * b1 - ws * a1, wc * b2 - ws * a2)),
        )

    def trajectory(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``x_d`` and ``ẋ_d`` at every time of ``times`` ``(K,)``, each of shape ``(K, 3)`` (the evaluator's form)."""
        positions, velocities = Ellipse.trajectories([self], times)
        return positions[:, 0], velocities[:, 0]

    @staticmethod
    def trajectories(ellipses: Sequence[Ellipse], times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`trajectory` of B ellipses at once, step-major: ``x_d`` and ``ẋ_d`` of shape ``(K, B, 3)``.

        Element by element the arithmetic of ``c + cos·major + sin·minor`` and ``(ω cos)·minor − (ω sin)·major``, in
        that order, a coordinate of every ellipse at a time, about :data:`_BLOCK_VALUES` angles at a time (their
        temporaries stay in the cache): a lockstep rollout reads one step of every sample, and 250 ellipses over 2501
        steps took 40 ms so, against 61 ms one ellipse at a time transposed afterwards.
        """
        times = np.asarray(times, dtype=float)
        if not ellipses:
            return np.empty((len(times), 0, 3)), np.empty((len(times), 0, 3))
        w = np.array([e.angular_speed for e in ellipses], dtype=float)
        phase = np.array([e.phase for e in ellipses], dtype=float)
        centre = np.array([e.centre for e in ellipses])
        major, minor = np.array([e._major for e in ellipses]), np.array([e._minor for e in ellipses])
        positions = np.empty((len(times), len(ellipses), 3))
        velocities = np.empty((len(times), len(ellipses), 3))
        steps = max(1, _BLOCK_VALUES // len(ellipses))
        for start in range(0, len(times), steps):
            block = slice(start, start + steps)
            angles = w * times[block, None] + phase
            cos, sin = np.cos(angles), np.sin(angles)
            w_cos, w_sin = w * cos, w * sin
            for j in range(3):
                x = cos * major[:, j]
                x += centre[:, j]
                x += sin * minor[:, j]
                positions[block, :, j] = x
                v = w_cos * minor[:, j]
                v -= w_sin * major[:, j]
                velocities[block, :, j] = v
        return positions, velocities

    def points(self, count: int = 32) -> np.ndarray:
        """``count`` points evenly spaced in angle around the whole ellipse, shape ``(count, 3)``."""
        angles = self.phase + np.linspace(0.0, 2 * np.pi, count, endpoint=False)
        return self.centre + np.stack([np.cos(angles), np.sin(angles)], axis=1) @ self._axes_matrix.T


#: Angles (steps × ellipses) of :meth:`Ellipse.trajectories` computed at a time: 128 steps of a batch of 250.
_BLOCK_VALUES = 32_000

#: The arrays of an :class:`Ellipse` and their shapes, in the order of its one packed array.
_ELLIPSE_ARRAYS = (
    ("centre", (3,)),
    ("semi_axes", (2,)),
    ("orientation", (3,)),
    ("_axes_matrix", (3, 2)),
    ("_major", (3,)),
    ("_minor", (3,)),
)


def _bind_arrays(ellipse: Ellipse, packed: np.ndarray) -> None:
    """Make the ellipse's arrays views of ``packed`` (their values, in :data:`_ELLIPSE_ARRAYS` order)."""
    object.__setattr__(ellipse, "_packed", packed)
    start = 0
    for name, shape in _ELLIPSE_ARRAYS:
        size = math.prod(shape)
        object.__setattr__(ellipse, name, packed[start : start + size].reshape(shape))
        start += size
    # centre, major and minor axis as Python floats, for position_and_velocity
    object.__setattr__(
        ellipse, "_floats", (*ellipse.centre.tolist(), *ellipse._major.tolist(), *ellipse._minor.tolist())
    )


def _unpickle_ellipse(packed: np.ndarray, angular_speed: float, phase: float) -> Ellipse:
    ellipse = object.__new__(Ellipse)
    _bind_arrays(ellipse, packed)
    object.__setattr__(ellipse, "angular_speed", angular_speed)
    object.__setattr__(ellipse, "phase", phase)
    return ellipse


Reference = FixedTarget | Ellipse
