"""The robot registry: a robot is data, and adding one is one :func:`register_robot` call.

Each :class:`Robot` names a URDF of ``example-robot-data``, the controlled frame and the base
frame its positions are expressed in, the start pose the samplers seed IK from, and, if the
default does not fit, its sample cuboid. Another package adds its robots through the entry-point group
``snac_gym.model.robots`` (as ``snac_gym.policies`` and ``snac_gym.tasks``): an entry point names a :class:`Robot`
(or a callable returning one), loaded and registered the first time the registry is read::

    [project.entry-points."snac_gym.robots"]
    myarm = "mypackage.robots:MYARM"

``urdf`` is a path relative to example-robot-data's ``robots`` folder, or an absolute path. Joint position and velocity
limits come from the URDF. Everything else (the envs, the controllers, the evaluator, the real-robot run) reaches
the robot through :class:`~snac_gym.model.kinematics.Kinematics` built from this entry.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from snac_gym.common.entry_points import EntryPointGroup
from snac_gym.model.ur_models import E_SERIES_URDF_DIR, UR_MODELS
from snac_gym.references import PAPER_Q0


@dataclass(frozen=True)
class Robot:
    """One arm.

    Attributes:
        name: Registry key (``robot=`` of the envs, ``--robot`` of the CLI).
        urdf: URDF path inside ``example-robot-data``'s ``robots/`` folder.
        ee_frame: URDF frame whose origin is the controlled point.
        base_frame: URDF frame, fixed to the world, in which positions are expressed.
        nominal_q: An elbow-up, wrist-down pose (rad) to seed inverse kinematics from; ``None``:
            the zero pose clipped to the joint limits.
        cuboid_low, cuboid_high: Corners of the sample cuboid (m, base frame); ``None``: the
            UR10 cuboid scaled by the arm's reach (:meth:`~snac_gym.sampling.SampleSpace.for_robot`).
        description: Its name in documentation.
        locked_joints: URDF joints held at their neutral value (clipped to their limits) and left
            out of the kinematics, e.g. the Panda's two finger joints: the controlled chain is the arm.
        env_prefix: The robot's part of its Gymnasium ids: ``UR10`` in ``snac_gym/UR10Reach-v0``
            (:mod:`snac_gym.envs.ids`); empty: the name in CamelCase (``ur10-limited`` → ``Ur10Limited``).
        demo_options: Reset-option values of ``snac-gym demo --robot`` by task name (``"q0"`` and the
            task's option key, e.g. ``{"q0": [...], "reach": {"target": [...]}}``); ``None``: the
            paper's θ₀ and references, which only a UR arm reaches.
    """

    name: str
    urdf: str
    ee_frame: str = "tool0"
    base_frame: str = "base"
    nominal_q: tuple[float, ...] | None = None
    cuboid_low: tuple[float, float, float] | None = None
    cuboid_high: tuple[float, float, float] | None = None
    description: str = ""
    locked_joints: tuple[str, ...] = ()
    demo_options: Mapping[str, Any] | None = field(default=None, hash=False)
    env_prefix: str = ""

    def __post_init__(self) -> None:
        if not self.env_prefix:
            camel = "".join(part[:1].upper() + part[1:] for part in re.split(r"[^0-9A-Za-z]+", self.name))
            object.__setattr__(self, "env_prefix", camel)
        if not re.fullmatch(r"[A-Za-z][0-9A-Za-z]*", self.env_prefix):
            raise ValueError(f"robot {self.name!r}: env_prefix must be letters and digits, got {self.env_prefix!r}")


#: The entry-point group of robots from other packages.
ENTRY_POINT_GROUP = "snac_gym.robots"  # the group keeps the name it was published under
#: Registered robots by name. Read it through :func:`robot_names`, :func:`all_robots` or :func:`get_robot`,
#: which load the entry points first.
ROBOTS: dict[str, Robot] = {}
_ENTRY_POINTS = EntryPointGroup(ENTRY_POINT_GROUP)


def register_robot(robot: Robot) -> Robot:
    """Add ``robot`` to :data:`ROBOTS`.

    Raises:
        ValueError: If the name or the id prefix is taken, or only one cuboid corner is given.
    """
    if robot.name in ROBOTS:
        raise ValueError(f"a robot named {robot.name!r} is already registered")
    if (robot.cuboid_low is None) != (robot.cuboid_high is None):
        raise ValueError(f"robot {robot.name!r}: give both cuboid corners or neither")
    prefixes = {other.env_prefix: other.name for other in ROBOTS.values()}
    if robot.env_prefix in prefixes:
        raise ValueError(
            f"robot {robot.name!r}: env_prefix {robot.env_prefix!r} is taken by {prefixes[robot.env_prefix]!r}"
        )
    ROBOTS[robot.name] = robot
    return robot


def load_entry_points(rescan: bool = False) -> None:
    """Register the robots of the ``snac_gym.robots`` entry points not loaded yet: the installed packages are
    read on the first call of the process (``rescan=True``: again, after installing one at run time).

    Raises:
        ValueError: Naming the entry point whose object is not a :class:`Robot`, or cannot be registered.
    """
    for entry, loaded in _ENTRY_POINTS.new(rescan):
        robot = loaded() if callable(loaded) and not isinstance(loaded, Robot) else loaded
        if not isinstance(robot, Robot):
            raise ValueError(
                f"{_ENTRY_POINTS.name(entry)} gives {type(robot).__name__}, not a snac_gym.model.robots.Robot"
            )
        try:
            if ROBOTS.get(robot.name) is not robot:
                register_robot(robot)
        except ValueError as error:
            raise ValueError(f"{_ENTRY_POINTS.name(entry)}: {error}") from None


def robot_names() -> tuple[str, ...]:
    """Names of the registered robots, in registration order (entry points included)."""
    load_entry_points()
    return tuple(ROBOTS)


def all_robots() -> tuple[Robot, ...]:
    """The registered robots, in registration order (entry points included)."""
    load_entry_points()
    return tuple(ROBOTS.values())


def get_robot(name: str) -> Robot:
    """The registered robot called ``name`` (case-insensitive).

    Raises:
        ValueError: If there is none, naming the registered ones.
    """
    key = name.lower() if isinstance(name, str) else name
    if key not in ROBOTS:
        load_entry_points()
    if key not in ROBOTS:
        raise ValueError(f"unknown robot {name!r}; choose one of {sorted(ROBOTS)}")
    return ROBOTS[key]


# The UR arms: tool0 in the frame the UR pendant shows ("base", π about z from base_link), so the
# paper's numbers work unchanged; the paper's θ₀ is elbow-up, wrist-down on all of them. The CB3 arms'
# URDFs are example-robot-data's; the e-series arms' are written from UR's DH parameters and datasheet
# (snac_gym.model.ur_models, tools/write_ur_urdfs.py), as example-robot-data has none.
for _model in UR_MODELS.values():
    register_robot(
        Robot(
            name=_model.name,
            urdf=(
                f"ur_description/urdf/{_model.name}_robot.urdf"
                if _model.series == "cb"
                else str(E_SERIES_URDF_DIR / f"{_model.name}.urdf")
            ),
            nominal_q=PAPER_Q0,
            description=f"Universal Robots {_model.label}",
            env_prefix=_model.label[:2] + _model.label[2:],
        )
    )


# The 7-DOF arms (docs/robots.md). Positions are of the tool centre point in the arm's base link;
# with 7 joints and a 3-D task the arm keeps a 4-D self-motion, so the seed pose and the cuboid
# are chosen where the samplers' IK stays on one elbow-up, wrist-down branch inside the joint
# limits. Each cuboid's corners are reachable with margin (tests/model/test_kinematics_7dof.py).
register_robot(
    Robot(
        name="panda",
        urdf="panda_description/urdf/panda.urdf",
        ee_frame="panda_hand_tcp",
        base_frame="panda_link0",
        # franka_ros' "ready" pose: elbow up, the hand pointing down, 0.31 m in front of the base.
        nominal_q=(0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785),
        cuboid_low=(0.30, -0.30, 0.20),
        cuboid_high=(0.60, 0.30, 0.60),
        description="Franka Emika Panda",
        env_prefix="Panda",
        locked_joints=("panda_finger_joint1", "panda_finger_joint2"),
        demo_options={
            "q0": [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785],
            "reach": [0.45, 0.2, 0.3],
            "track": {"centre": [0.45, 0.0, 0.4], "radius": 0.1},
        },
    )
)
register_robot(
    Robot(
        name="xarm7",
        urdf="xarm_description/urdf/xarm7.urdf",
        ee_frame="link_eef",
        base_frame="link_base",
        # Elbow up, the flange pointing down, 0.41 m in front of the base.
        nominal_q=(0.0, -0.2, 0.0, 0.9, 0.0, 1.1, 0.0),
        cuboid_low=(0.25, -0.30, 0.15),
        cuboid_high=(0.55, 0.30, 0.50),
        description="UFACTORY xArm7",
        env_prefix="XArm7",
        demo_options={
            "q0": [0.0, -0.2, 0.0, 0.9, 0.0, 1.1, 0.0],
            "reach": [0.45, 0.2, 0.25],
            "track": {"centre": [0.4, 0.0, 0.35], "radius": 0.1},
        },
    )
)
