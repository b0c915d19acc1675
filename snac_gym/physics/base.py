"""What every engine shares: the arm contracts the env core and the lockstep engine drive, the physics
vocabulary (:data:`PHYSICS`, checked by :func:`check_physics`) and the checks of the timing and image size."""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from snac_gym.common.extras import require_installed
from snac_gym.common.validation import real_number, whole_number

#: The arm models: ``physics=`` of ``gym.make``, ``--engine`` of ``snac-gym evaluate`` (the one vocabulary).
PHYSICS = ("pybullet", "kinematic", "mujoco")
#: Those that simulate the arm (the lockstep engine's arms, ``snac-gym bench``): all but the exact model.
SIMULATED = ("pybullet", "mujoco")
#: The extra that installs each optional engine (PyBullet and the exact model come with the package).
ENGINE_EXTRAS = {"mujoco": "mujoco"}
#: How PyBullet solves its velocity motors each physics step (``pybullet_solver=`` of the envs): ``"pgs"``, its
#: default projected Gauss-Seidel, iterated up to a residual, which leaves a steady lag under gravity (docs/physics.md);
#: ``"dantzig"``, its MLCP solver's direct (Dantzig) pivoting, which meets every motor below its force bound exactly.
PYBULLET_SOLVERS = ("pgs", "dantzig")


def check_physics(physics: Any, allowed: tuple[str, ...] = PHYSICS, what: str = "physics") -> str:
    """``physics`` if it names an engine of ``allowed`` (a subset of :data:`PHYSICS`).

    Raises:
        ValueError: Naming ``what``, the value and the choices.
    """
    if not isinstance(physics, str) or physics not in allowed:
        raise ValueError(f"{what} must be one of {allowed}, got {physics!r}")
    return physics


def require_engine(physics: str) -> None:
    """Where ``physics`` is an optional engine, that its extra is installed (found, not imported: a process that only
    hands the engine's work to others, as the evaluator's main process, need not load it).

    Raises:
        MissingExtraError: As the engine's own import would, before any work that the engine would end.
    """
    extra = ENGINE_EXTRAS.get(physics)
    if extra is not None:
        require_installed(physics, extra, f"physics={physics!r}")


def check_pybullet_solver(solver: Any) -> str:
    """``solver`` if it is one of :data:`PYBULLET_SOLVERS` (checked whatever the engine, so that a typo is not
    ignored where it would not be read).

    Raises:
        ValueError: Naming ``pybullet_solver``, the value and the choices.
    """
    return check_physics(solver, PYBULLET_SOLVERS, "pybullet_solver")


#: Largest rendered image side, pixels (TinyRenderer allocates width x height buffers in C++).
MAX_IMAGE_SIDE = 8192


def check_image_size(width: Any, height: Any) -> tuple[int, int]:
    """``(width, height)`` as ints, each in [1, :data:`MAX_IMAGE_SIDE`].

    A negative size aborts the interpreter inside PyBullet (``std::bad_alloc``) and zero divides
    by zero or gives an empty image, so they are refused before they reach it.

    Raises:
        ValueError: Naming the bad side and the bound.
    """
    sides = []
    for name, value in (("render_width", width), ("render_height", height)):
        whole = isinstance(value, (int, np.integer)) or (isinstance(value, float) and value.is_integer())
        if isinstance(value, bool) or not whole or not 1 <= value <= MAX_IMAGE_SIDE:
            raise ValueError(f"{name} must be a whole number of pixels in [1, {MAX_IMAGE_SIDE}], got {value!r}")
        sides.append(int(value))
    return sides[0], sides[1]


#: Longest control period accepted, s: a velocity command held for longer is no longer the
#: paper's velocity-level control (its UR10 runs at 8 ms).
MAX_DT = 1.0


#: The shortest control period: 1 µs (1 MHz; UR controllers run at 125 and 500 Hz). Shorter ones are no
#: control loop, and their step counts overflow (dt = 1e-320 made 1/dt infinite).
MIN_DT = 1e-6
#: Most physics steps per control period: 1000 (an 8 µs physics step at the paper's 8 ms). More would only
#: make every step take seconds (10⁹ would hang the first step).
MAX_SUBSTEPS = 1000


def check_timing(dt: Any, n_substeps: Any) -> tuple[float, int]:
    """``(dt, n_substeps)`` of a physics engine, checked: a real :data:`MIN_DT` ≤ dt ≤ :data:`MAX_DT` s and a whole
    1 ≤ n_substeps ≤ :data:`MAX_SUBSTEPS` (no bools, strings or complex numbers: :mod:`snac_gym.common.validation`).

    Raises:
        ValueError: Naming the bad one.
    """
    return (real_number("dt (s)", dt, MIN_DT, MAX_DT), whole_number("n_substeps", n_substeps, 1, MAX_SUBSTEPS))


@runtime_checkable
class Arm(Protocol):
    """A joint-velocity-controlled arm stepped one control period at a time."""

    dt: float

    def reset(self, q0: np.ndarray) -> None:
        """Pose the joints at ``q0``, at rest, with no command held."""

    def apply(self, u: np.ndarray) -> None:
        """Hold the command ``u`` (rad/s) for one control period."""

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured ``(θ, θ̇)``."""

    def restore(self, q: np.ndarray, qdot: np.ndarray, command: np.ndarray) -> None:
        """Put a pickled episode back: the joints at ``(q, qdot)`` holding ``command``."""

    def close(self) -> None:
        """Release the simulator (safe to call twice)."""


class ArmBatch(Protocol):
    """B arms stepped together, one command row each: what the evaluator's lockstep engine drives
    (:func:`snac_gym.rollout.simulate_arms`)."""

    def __len__(self) -> int:
        """B."""

    def reset(self, q0: np.ndarray) -> None:
        """Pose arm i at row i of ``q0`` ``(B, m)``, at rest."""

    def apply(self, commands: np.ndarray) -> None:
        """Hold row i of ``commands`` ``(B, m)`` on arm i for one control period."""

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured ``(θ, θ̇)`` of all arms, ``(B, m)`` each."""

    def close(self) -> None:
        """Release the simulators."""


def _stacked(states: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """``(θ, θ̇)`` of each arm → ``(B, m)`` θ and ``(B, m)`` θ̇."""
    return np.array([q for q, _ in states]), np.array([qdot for _, qdot in states])


class ArmList:
    """An :class:`ArmBatch` of independent :class:`Arm` objects (e.g. MuJoCo replicas), stepped one by one."""

    def __init__(self, arms: list[Arm]) -> None:
        self.arms = list(arms)

    def __len__(self) -> int:
        return len(self.arms)

    def reset(self, q0: np.ndarray) -> None:
        for arm, row in zip(self.arms, q0, strict=True):
            arm.reset(row)

    def apply(self, commands: np.ndarray) -> None:
        for arm, command in zip(self.arms, commands, strict=True):
            arm.apply(command)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        return _stacked([arm.joint_state() for arm in self.arms])

    def close(self) -> None:
        for arm in self.arms:
            arm.close()


def scene_of(arm: Any, kinematics: Any, space: Any, width: int, height: int, camera: Any = None) -> Any:
    """What a frame of ``arm`` shows: its engine's scene (the arm's ``scene`` method).

    Raises:
        ValueError: For an arm with nothing to draw (the kinematic model).
    """
    make_scene = getattr(arm, "scene", None)
    if make_scene is None:
        raise ValueError(f"{type(arm).__name__} has no scene to render")
    return make_scene(kinematics, space, width, height, camera)
