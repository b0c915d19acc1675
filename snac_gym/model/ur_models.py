"""The Universal Robots models: each one's published DH parameters and datasheet limits, in one table.

:data:`UR_MODELS` serves three readers: the robot registry (the e-series arms' URDFs are written from
their DH rows by :func:`urdf_text`, since ``example-robot-data`` ships only the CB3 arms), the UR
controller emulator (which computes the TCP pose from the DH rows, as the controller does) and the
real-arm safety layer (which never commands a joint faster than the datasheet allows, whatever the
URDF says).

Sources, as named in :attr:`URModel.source`:

* DH parameters: Universal Robots, "DH parameters for calculations of kinematics and dynamics"
  (universal-robots.com support article); the same numbers are in ``ur_description``'s
  ``config/<model>/default_kinematics.yaml`` (ros-industrial/universal_robot).
* Joint ranges and speeds: each model's user manual, "Technical specifications" (CB3 manuals version
  3.13, e-Series manuals version 5.8), as quoted in ``ur_description``'s ``config/<model>/joint_limits.yaml``.
* Reach: the same technical specifications.

The CB3 URDFs of ``example-robot-data`` state speeds a little above the datasheet's on the UR10
(2.16 rad/s = 123.8 °/s on the base and shoulder against 120 °/s; 3.2 rad/s = 183 °/s on the wrists
against 180 °/s): :func:`datasheet_velocity_limits` is the bound a real arm is held to.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: The DH twist αᵢ of every UR arm (rad): the same for every model.
DH_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
#: The controller's cycle by series (Hz): CB3 (``"cb"``) and e-Series (``"e"``); ur_rtde streams at this rate.
SERIES_FREQUENCY = {"cb": 125.0, "e": 500.0}
_CB3_MANUAL = "Universal Robots {model} User Manual (CB3, version 3.13), technical specifications"
_E_MANUAL = "Universal Robots e-Series User Manual, {model} (version 5.8), technical specifications"
_DH_SOURCE = "Universal Robots, 'DH parameters for calculations of kinematics and dynamics'"


#: Six numbers, one per joint (base first).
_Six = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class URModel:
    """One UR arm model.

    Attributes:
        name: Registry name (``ur5e``).
        series: ``"cb"`` (CB3) or ``"e"`` (e-Series).
        dh: (d1, a2, a3, d4, d5, d6), m: the nonzero DH lengths.
        max_speed_deg: Datasheet maximum speed of each joint, °/s (base first).
        reach: Datasheet reach, m.
        effort: Rated joint torque, N·m (the URDF's ``effort``; size 0, 1, 2 and 3 joints).
        mass: Datasheet weight of the arm, kg (the written URDFs spread it over the links).
    """

    name: str
    series: str
    dh: tuple[float, float, float, float, float, float]
    max_speed_deg: tuple[float, float, float, float, float, float]
    reach: float
    effort: tuple[float, float, float, float, float, float]
    mass: float

    @property
    def label(self) -> str:
        """``UR5e``: the name on the arm."""
        return "UR" + self.name[2:]

    @property
    def source(self) -> dict[str, str]:
        """Where each number comes from."""
        manual = (_CB3_MANUAL if self.series == "cb" else _E_MANUAL).format(model=self.label)
        return {"dh": _DH_SOURCE, "joint_ranges": manual, "speeds": manual, "reach": manual}

    @property
    def frequency(self) -> float:
        """The controller's cycle, Hz (125 on CB3, 500 on the e-series)."""
        return SERIES_FREQUENCY[self.series]


def _model(name: str, series: str, dh: _Six, speeds: _Six, reach: float, effort: _Six, mass: float) -> URModel:
    return URModel(name, series, dh, speeds, reach, effort, mass)


#: Every UR model the project knows, by registry name.
UR_MODELS: dict[str, URModel] = {
    m.name: m
    for m in (
        _model(
            "ur3",
            "cb",
            (0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
            (180, 180, 180, 360, 360, 360),
            0.500,
            (56, 56, 28, 12, 12, 12),
            11.0,
        ),
        _model(
            "ur5",
            "cb",
            (0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
            (180, 180, 180, 180, 180, 180),
            0.850,
            (150, 150, 150, 28, 28, 28),
            18.4,
        ),
        _model(
            "ur10",
            "cb",
            (0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922),
            (120, 120, 180, 180, 180, 180),
            1.300,
            (330, 330, 150, 56, 56, 56),
            28.9,
        ),
        _model(
            "ur3e",
            "e",
            (0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921),
            (180, 180, 180, 360, 360, 360),
            0.500,
            (56, 56, 28, 12, 12, 12),
            11.2,
        ),
        _model(
            "ur5e",
            "e",
            (0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996),
            (180, 180, 180, 180, 180, 180),
            0.850,
            (150, 150, 150, 28, 28, 28),
            20.6,
        ),
        _model(
            "ur10e",
            "e",
            (0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655),
            (120, 120, 180, 180, 180, 180),
            1.300,
            (330, 330, 150, 56, 56, 56),
            33.5,
        ),
        _model(
            "ur16e",
            "e",
            (0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655),
            (120, 120, 180, 180, 180, 180),
            0.900,
            (330, 330, 150, 56, 56, 56),
            33.1,
        ),
    )
}
#: Where the e-series URDFs written by :func:`urdf_text` are shipped.
E_SERIES_URDF_DIR = Path(__file__).parents[1] / "data" / "urdf"
#: Datasheet joint range of every UR joint: ±360°. The URDFs hold the elbow to ±180°, the range its
#: construction allows (the shoulder is in the way beyond it).
DATASHEET_RANGE = 2 * math.pi


def get_ur_model(name: str) -> URModel:
    """The UR model called ``name`` (case-insensitive).

    Raises:
        ValueError: Naming the known models.
    """
    key = name.lower() if isinstance(name, str) else name
    if key not in UR_MODELS:
        raise ValueError(f"{name!r} is not a UR model; choose one of {', '.join(UR_MODELS)}")
    return UR_MODELS[key]


def series_of(robot: str, series: str | None = None) -> str:
    """The controller series a run of ``robot`` uses: ``series``, or the model's own when ``None``.

    Raises:
        ValueError: For an unknown series, or the e-Series' 500 Hz asked of a CB3 arm (an e-Series arm may
            stream at the CB3's 125 Hz).
    """
    model = get_ur_model(robot)
    if series is None:
        return model.series
    if series not in SERIES_FREQUENCY:
        raise ValueError(f"--series must be one of {', '.join(SERIES_FREQUENCY)}, got {series!r}")
    if series == "e" and model.series == "cb":
        raise ValueError(
            f"--series e is the e-Series' 500 Hz; the {model.label} is a CB3 arm (125 Hz): "
            "use --series cb, or leave it out"
        )
    return series


def datasheet_velocity_limits(name: str) -> np.ndarray:
    """The datasheet's maximum joint speeds of model ``name``, rad/s."""
    limits: np.ndarray = np.radians(np.array(get_ur_model(name).max_speed_deg, dtype=float))
    return limits


def velocity_limits(robot: str, urdf_limits: np.ndarray) -> np.ndarray:
    """The joint speeds (rad/s) a real ``robot`` may be commanded: its URDF's, and no more than its datasheet's
    where it is a UR model (other robots: the URDF's)."""
    urdf_limits = np.asarray(urdf_limits, dtype=float)
    if not isinstance(robot, str) or robot.lower() not in UR_MODELS:
        return urdf_limits.copy()
    bounded: np.ndarray = np.minimum(urdf_limits, datasheet_velocity_limits(robot))
    return bounded


def _dh(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1.0]])


def flange_transform(name: str, q: np.ndarray) -> np.ndarray:
    """Base-frame transform of the flange (``tool0``) of model ``name`` at joint angles ``q``, from its DH rows."""
    d1, a2, a3, d4, d5, d6 = get_ur_model(name).dh
    ds, as_ = (d1, 0.0, 0.0, d4, d5, d6), (0.0, a2, a3, 0.0, 0.0, 0.0)
    transform = np.eye(4)
    for theta, d, a, alpha in zip(q, ds, as_, DH_ALPHA):
        transform = transform @ _dh(float(theta), d, a, alpha)
    return transform


# -- the written URDFs -------------------------------------------------------------------------------------
_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
_LINKS = ("shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link")
# The arm's weight over base, shoulder, upper arm, forearm and the three wrists: the UR5e's published
# link masses, normalised. The written URDFs are for kinematics and velocity servos; the split only
# gives the physics engines plausible inertias.
_MASS_SHARE = (0.19, 0.18, 0.39, 0.14, 0.066, 0.063, 0.018)
_RADIUS = 0.06  # m, the links' cylinders at the UR5e's size, scaled by reach


def _origins(dh: tuple[float, ...]) -> list[tuple[tuple[float, float, float], tuple[float, float, float]]]:
    """(xyz, rpy) of each joint in its parent link: UR's DH rows in ``ur_description``'s layout
    (joint i carries dᵢ along its parent's z and the previous row's aᵢ₋₁, αᵢ₋₁)."""
    d1, a2, a3, d4, d5, d6 = dh
    half = math.pi / 2
    return [
        ((0.0, 0.0, d1), (0.0, 0.0, 0.0)),
        ((0.0, 0.0, 0.0), (half, 0.0, 0.0)),
        ((a2, 0.0, 0.0), (0.0, 0.0, 0.0)),
        ((a3, 0.0, d4), (0.0, 0.0, 0.0)),
        ((0.0, -d5, 0.0), (half, 0.0, 0.0)),
        ((0.0, d6, 0.0), (half, math.pi, math.pi)),
    ]


def _fmt(values: Iterable[float]) -> str:
    return " ".join(f"{float(v):.17g}" for v in values)


def _cylinder(segment: np.ndarray, radius: float) -> str:
    """A cylinder from the link's origin to ``segment`` (its next joint), as visual and collision."""
    length = float(np.linalg.norm(segment))
    if length < 1e-6:
        return ""
    axis = segment / length
    # rpy turning z onto the axis: pitch about y, then yaw about z.
    pitch, yaw = math.acos(max(-1.0, min(1.0, axis[2]))), math.atan2(axis[1], axis[0])
    geometry = f'<geometry><cylinder radius="{radius:.4g}" length="{length:.17g}"/></geometry>'
    origin = f'<origin xyz="{_fmt(segment / 2)}" rpy="0 {pitch:.17g} {yaw:.17g}"/>'
    return f"    <visual>{origin}{geometry}</visual>\n    <collision>{origin}{geometry}</collision>\n"


def _link(name: str, mass: float, segment: np.ndarray | None, radius: float) -> str:
    inertia = mass * radius**2 / 2
    body = _cylinder(segment, radius) if segment is not None else ""
    return (
        f'  <link name="{name}">\n{body}'
        f'    <inertial><mass value="{mass:.4g}"/><origin xyz="0 0 0"/>'
        f'<inertia ixx="{inertia:.4g}" ixy="0" ixz="0" iyy="{inertia:.4g}" iyz="0" izz="{inertia:.4g}"/></inertial>\n'
        "  </link>\n"
    )


def urdf_text(name: str) -> str:
    """A URDF of model ``name`` written from its DH rows and datasheet limits, in ``ur_description``'s frames:
    ``base_link`` (the mounting flange), ``base`` (π about z, the frame the controller reports in) and
    ``tool0`` (the tool flange); cylinders for links. ``tools/write_ur_urdfs.py`` writes the shipped files.
    """
    model = get_ur_model(name)
    origins = _origins(model.dh)
    masses = [share * model.mass for share in _MASS_SHARE]
    radius = _RADIUS * model.reach / 0.85
    speeds = datasheet_velocity_limits(name)
    parts = [
        '<?xml version="1.0"?>\n',
        f"<!-- {model.label}: written by snac_gym.model.ur_models.urdf_text from {model.source['dh']} and the\n"
        f"     {model.source['speeds']}. Kinematics and velocity limits are the published ones; the links are\n"
        "     cylinders and their masses an estimate. Do not edit: run tools/write_ur_urdfs.py. -->\n",
        f'<robot name="{model.name}">\n',
        _link("base_link", masses[0], np.array([0.0, 0.0, model.dh[0] * 0.5]), radius),
        '  <link name="base_link_inertia"/>\n',
        '  <joint name="base_link-base_link_inertia" type="fixed"><parent link="base_link"/>'
        f'<child link="base_link_inertia"/><origin xyz="0 0 0" rpy="0 0 {math.pi:.17g}"/></joint>\n',
    ]
    parent = "base_link_inertia"
    for i, (joint, link) in enumerate(zip(_JOINTS, _LINKS)):
        xyz, rpy = origins[i]
        segment = np.array(origins[i + 1][0]) if i + 1 < len(origins) else None
        parts.append(_link(link, masses[i + 1], segment, radius * (0.75 if i >= 3 else 1.0)))
        lower, upper = (-math.pi, math.pi) if joint == "elbow" else (-DATASHEET_RANGE, DATASHEET_RANGE)
        parts.append(
            f'  <joint name="{joint}_joint" type="revolute"><parent link="{parent}"/><child link="{link}"/>'
            f'<origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/><axis xyz="0 0 1"/>'
            f'<limit lower="{lower:.17g}" upper="{upper:.17g}" effort="{model.effort[i]:g}" '
            f'velocity="{speeds[i]:.17g}"/>'
            "</joint>\n"
        )
        parent = link
    parts += [
        '  <link name="flange"/>\n  <link name="tool0"/>\n  <link name="base"/>\n',
        '  <joint name="wrist_3-flange" type="fixed"><parent link="wrist_3_link"/><child link="flange"/>'
        f'<origin xyz="0 0 0" rpy="0 {-math.pi / 2:.17g} {-math.pi / 2:.17g}"/></joint>\n',
        '  <joint name="flange-tool0" type="fixed"><parent link="flange"/><child link="tool0"/>'
        f'<origin xyz="0 0 0" rpy="{math.pi / 2:.17g} 0 {math.pi / 2:.17g}"/></joint>\n',
        '  <joint name="base_link-base_fixed_joint" type="fixed"><parent link="base_link"/><child link="base"/>'
        f'<origin xyz="0 0 0" rpy="0 0 {math.pi:.17g}"/></joint>\n',
        "</robot>\n",
    ]
    return "".join(parts)
