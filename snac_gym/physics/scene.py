"""What a rendered frame shows: a floor, a coloured arm, the reference and its path, framed by one camera.

The camera is placed once per env so that the arm's base, its links at the seed pose and the
whole sample cuboid fit in the image with a margin (``tests/physics/test_scene_rendering.py`` projects every
link origin over random episodes and finds them inside). The target is a red sphere; for a
tracking task the ellipse is drawn as a ring of small yellow spheres. PyBullet's TinyRenderer
draws on the CPU, so a frame costs tens of milliseconds: the env renders a new image every
``render_every`` control steps and repeats it in between, and declares ``render_fps`` = 1/Δt,
so a recorded video plays in real time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from snac_gym.common.validation import real_array, real_number
from snac_gym.model.kinematics import Kinematics
from snac_gym.references import Reference
from snac_gym.sampling import SampleSpace, sample_seed_pose

#: Vertical field of view of the camera, degrees.
FIELD_OF_VIEW = 45.0
#: Fraction of the image (per axis, from its centre) the framed points fill: the rest is room for
#: the links' swing during an episode.
FILL = 0.75
#: Points of the drawn ellipse path.
PATH_POINTS = 48
#: Link colours, cycled (dark blue and orange: they stand out from the grey floor and the white sky).
LINK_COLOURS = ((0.16, 0.25, 0.45, 1.0), (0.93, 0.55, 0.16, 1.0))
FLOOR_COLOUR = (0.55, 0.57, 0.6, 1.0)
TARGET_COLOUR = (0.85, 0.1, 0.1, 1.0)
PATH_COLOUR = (0.95, 0.8, 0.1, 1.0)
CUBOID_COLOUR = (0.35, 0.38, 0.42, 1.0)
#: Where unused path markers wait (under the floor, out of view), m.
PARKED = (0.0, 0.0, -5.0)
#: Marker radii and the cuboid bars' half width, m.
TARGET_RADIUS, PATH_RADIUS, EDGE_HALF_WIDTH = 0.035, 0.009, 0.002
#: Half extents of the floor slab, m (its top at z = 0).
FLOOR_HALF_EXTENTS = (6.0, 6.0, 0.005)
#: Near and far clipping planes, m.
NEAR, FAR = 0.05, 20.0


def project(points: np.ndarray, view: list[float], projection: list[float], width: int, height: int) -> np.ndarray:
    """Pixel coordinates ``(u, v)`` of world points through PyBullet's column-major view and projection matrices.

    ``u`` runs right from the image's left edge and ``v`` down from its top edge; a point is
    in the image when 0 ≤ u < width and 0 ≤ v < height (and in front of the camera: the
    returned depth column, clip-space w, is positive).

    Returns:
        ``(N, 3)``: u, v and w.
    """
    points = np.atleast_2d(np.asarray(points, dtype=float))
    homogeneous = np.hstack([points, np.ones((len(points), 1))])
    view_m = np.asarray(view, dtype=float).reshape(4, 4).T
    projection_m = np.asarray(projection, dtype=float).reshape(4, 4).T
    clip = homogeneous @ (projection_m @ view_m).T
    ndc = clip[:, :3] / clip[:, 3:4]
    u = (ndc[:, 0] + 1.0) / 2.0 * width
    v = (1.0 - ndc[:, 1]) / 2.0 * height
    return np.column_stack([u, v, clip[:, 3]])


def look_at(eye: np.ndarray, target: np.ndarray, up: Any = (0.0, 0.0, 1.0)) -> list[float]:
    """The OpenGL view matrix (column-major, 16 floats) of a camera at ``eye`` looking at ``target``:
    PyBullet's ``computeViewMatrix``, in NumPy."""
    eye = np.asarray(eye, dtype=float)
    forward = np.asarray(target, dtype=float) - eye
    forward /= np.linalg.norm(forward)
    side = np.cross(forward, up)
    side /= np.linalg.norm(side)
    matrix = np.eye(4)
    matrix[0, :3], matrix[1, :3], matrix[2, :3] = side, np.cross(side, forward), -forward
    matrix[:3, 3] = -matrix[:3, :3] @ eye
    return matrix.T.ravel().tolist()


def perspective(fov: float, aspect: float, near: float, far: float) -> list[float]:
    """The OpenGL projection matrix (column-major) of a vertical field of view ``fov`` (degrees):
    PyBullet's ``computeProjectionMatrixFOV``, in NumPy."""
    focal = 1.0 / math.tan(math.radians(fov) / 2.0)
    matrix = np.zeros((4, 4))
    matrix[0, 0], matrix[1, 1] = focal / aspect, focal
    matrix[2, 2], matrix[2, 3], matrix[3, 2] = (far + near) / (near - far), 2.0 * far * near / (near - far), -1.0
    return matrix.T.ravel().tolist()


@dataclass(frozen=True)
class Camera:
    """Where the camera is and what it sees: ``eye`` looking at ``target`` (world frame, up +z), and the
    matching OpenGL matrices (column-major, for :func:`project` and PyBullet)."""

    eye: np.ndarray
    target: np.ndarray
    view: list[float]
    projection: list[float]


@dataclass(frozen=True)
class CameraOptions:
    """Where the camera looks from, in panda-gym's and PyBullet's terms; ``None``: fitted to the scene.

    Attributes:
        distance: From the camera to its target, m, in (0, 20].
        yaw: The camera's azimuth about the world's z axis, degrees (PyBullet's
            ``computeViewMatrixFromYawPitchRoll``: 0 looks along +y, 90 along −x).
        pitch: Its elevation, degrees in [−89, 89]; negative looks down (panda-gym's default is −30).
        target: The point it looks at, world frame, m.
    """

    distance: float | None = None
    yaw: float | None = None
    pitch: float | None = None
    target: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.distance is not None:
            object.__setattr__(
                self, "distance", real_number("render_distance (m)", self.distance, 0.0, FAR, low_open=True)
            )
        if self.yaw is not None:
            object.__setattr__(self, "yaw", real_number("render_yaw (degrees)", self.yaw, -360.0, 360.0))
        if self.pitch is not None:
            object.__setattr__(self, "pitch", real_number("render_pitch (degrees)", self.pitch, -89.0, 89.0))
        if self.target is not None:
            target = real_array("render_target_position (m)", self.target, (3,))
            if np.abs(target).max() > FAR:
                raise ValueError(
                    f"render_target_position (m) must lie within {FAR:g} m of the origin, got {self.target}"
                )
            object.__setattr__(self, "target", tuple(float(t) for t in target))

    def direction(self, fitted: np.ndarray) -> np.ndarray:
        """The unit vector from the target to the camera: ``fitted``'s, with the given yaw and pitch."""
        if self.yaw is None and self.pitch is None:
            return fitted
        yaw = math.radians(self.yaw) if self.yaw is not None else math.atan2(fitted[0], -fitted[1])
        pitch = math.radians(self.pitch) if self.pitch is not None else -math.asin(float(fitted[2]))
        return np.array([math.sin(yaw) * math.cos(pitch), -math.cos(yaw) * math.cos(pitch), -math.sin(pitch)])


def fit_camera(
    points: np.ndarray,
    kinematics: Kinematics,
    width: int,
    height: int,
    options: CameraOptions | None = None,
    also: np.ndarray | None = None,
) -> Camera:
    """The camera of every engine's scene: it sees ``points`` (world frame) from the arm's front, a
    little from above, recentred and scaled so that they fill :data:`FILL` of the image (the rest is
    room for the links' swing). ``options`` fixes any of distance, yaw, pitch and target instead.
    ``also``: points the frame must show too; the camera is fitted to them as well only where the
    first fit leaves one out (the start poses of a redundant arm), so that a frame that shows them
    already keeps its scale."""
    camera = _fit_camera(points, kinematics, width, height, options or CameraOptions())
    if also is None or not len(also):
        return camera
    pixels = project(np.asarray(also, dtype=float), camera.view, camera.projection, width, height)
    ndc = np.column_stack([pixels[:, 0] / width * 2 - 1, 1 - pixels[:, 1] / height * 2])
    if np.abs(ndc).max() <= FILL:  # inside the part of the frame the fitted points fill: the links' bodies fit too
        return camera
    return _fit_camera(np.vstack([points, also]), kinematics, width, height, options or CameraOptions())


def _fit_camera(points: np.ndarray, kinematics: Kinematics, width: int, height: int, options: CameraOptions) -> Camera:
    aspect = width / height
    projection = perspective(FIELD_OF_VIEW, aspect, NEAR, FAR)
    towards = kinematics.base_to_world(np.array([-1.0, -0.6, 0.0])) - kinematics.base_to_world(np.zeros(3))
    direction = np.array([towards[0], towards[1], 0.0]) / np.linalg.norm(towards[:2])
    direction = direction + np.array([0.0, 0.0, 0.35])
    direction = options.direction(direction / np.linalg.norm(direction))
    target = np.array(options.target) if options.target is not None else (points.min(axis=0) + points.max(axis=0)) / 2.0
    distance = options.distance or 3.0 * float(np.linalg.norm(points - target, axis=1).max())
    if options.target is not None and options.distance is not None:
        return Camera(target + distance * direction, target, look_at(target + distance * direction, target), projection)
    for _ in range(4):  # recentre the points' image and scale them to FILL of the frame (what is not given)
        view = look_at(target + distance * direction, target)
        pixels = project(points, view, projection, width, height)
        ndc = np.column_stack([pixels[:, 0] / width * 2 - 1, 1 - pixels[:, 1] / height * 2])
        low, high = ndc.min(axis=0), ndc.max(axis=0)
        right = np.cross(-direction, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, -direction)
        half_height = math.tan(math.radians(FIELD_OF_VIEW) / 2.0) * distance
        centre = (low + high) / 2.0
        if options.target is None:
            target = target + right * centre[0] * half_height * aspect + up * centre[1] * half_height
        if options.distance is None:
            distance *= float(max(high - low)) / 2.0 / FILL
    view = look_at(target + distance * direction, target)
    return Camera(target + distance * direction, target, view, projection)


def cuboid_edges(space: SampleSpace) -> list[tuple[np.ndarray, np.ndarray]]:
    """The sample cuboid's twelve edges as ``(centre, half-extents)`` of thin bars (base frame, axis-aligned):
    where random targets and ellipses come from."""
    low, high = np.asarray(space.low, dtype=float), np.asarray(space.high, dtype=float)
    centre, half = (low + high) / 2.0, (high - low) / 2.0
    edges = []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        extents = np.full(3, EDGE_HALF_WIDTH)
        extents[axis] = half[axis]
        for sign_a in (-1, 1):
            for sign_b in (-1, 1):
                corner = centre.copy()
                corner[others[0]] += sign_a * half[others[0]]
                corner[others[1]] += sign_b * half[others[1]]
                edges.append((corner, extents))
    return edges


def base_yaw(kinematics: Kinematics) -> float:
    """The base frame's rotation about the world's z axis, rad (the bars stay aligned with it)."""
    x_axis = kinematics.base_to_world(np.array([1.0, 0.0, 0.0])) - kinematics.base_to_world(np.zeros(3))
    return math.atan2(x_axis[1], x_axis[0])


#: Start poses the default camera frames, besides the nominal one: an episode starts at a random seed
#: pose, and a redundant arm's elbow rises far above the cuboid in some (the Panda's frame was cut at the top).
FRAMED_START_POSES = 12


def framing_configurations(kinematics: Kinematics, space: SampleSpace) -> list[np.ndarray]:
    """The start poses whose links every default frame shows too: :data:`FRAMED_START_POSES` seed
    poses as ``reset`` draws them (a fixed generator: the same camera in every run)."""
    rng = np.random.default_rng(0)
    return [sample_seed_pose(kinematics, rng, space) for _ in range(FRAMED_START_POSES)]


def framing_corners(space: SampleSpace) -> np.ndarray:
    """The sample cuboid's eight corners (base frame), which every frame shows."""
    return np.array(
        [
            [x, y, z]
            for x in (space.low[0], space.high[0])
            for y in (space.low[1], space.high[1])
            for z in (space.low[2], space.high[2])
        ]
    )


def path_positions(reference: Reference, kinematics: Kinematics, markers: int) -> list[Any]:
    """World positions of the ``markers`` path markers for ``reference``: its path's points (the ellipse),
    the rest parked out of view (all of them for a fixed target, which has no path)."""
    points: np.ndarray | list[np.ndarray] = reference.points(PATH_POINTS)
    if len(points) < 2:
        points = []
    return [kinematics.base_to_world(points[i]) if i < len(points) else PARKED for i in range(markers)]


def default_render_every(dt: float, frame_rate: float = 25.0) -> int:
    """Control steps between two new frames for about ``frame_rate`` distinct images per second."""
    return max(1, round(1.0 / (dt * frame_rate)))
