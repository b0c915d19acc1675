"""Pose tasks: reach a full end-effector pose, or follow an ellipse at a fixed orientation.

Task coordinates are ``x = [p; log₃ R]`` (m, rad) and the error is ``e = [p − p_d; log₃(R R_dᵀ)]``
(:class:`~snac_gym.model.kinematics.PoseKinematics`): position in metres, orientation in radians, both in
the base frame, with the 6-row ``LOCAL_WORLD_ALIGNED`` Jacobian. The cost ``eᵀQe + uᵀRu`` weighs
both blocks with Q = I₆ by default, so 1 mrad of orientation error costs as much as 1 mm of
position error; pass ``Q=np.diag([1, 1, 1, w², w², w²])`` to price a radian as ``w`` metres.
Success is ``‖e‖ ≤ 1e-3`` (1 mm and 1 mrad together) for reach, a mean of 5e-3 over the second half
for tracking, as for the position tasks.

The tasks are opt-in: :func:`register_pose_tasks` adds them and their Gymnasium ids, one per
registered robot: ``snac_gym/UR10PoseReach-v0``, ``snac_gym/PandaPoseEllipseTrack-v0``, ... (the
7-DOF arms are redundant for them). ``snac-gym evaluate --task pose-reach`` (or
``pose-track``) registers them and runs them on the lockstep engine, which applies the same
``task_error``; the ``optimal`` reference solves for the log₃ error with its exact Jacobian
(:func:`pose_errors_and_jacobians`).

Samples CSV (:mod:`snac_gym.evaluation.samples`): a pose row holds its position reference in the position
task's columns (``target_0..2`` for ``pose-reach``, the ellipse columns for ``pose-track``) and the
target orientation in :data:`ROTVEC_COLUMNS` ``rotvec_0..2``: the rotation vector r_d = log₃ R_d
(rad, base frame; axis times angle).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, cast

import numpy as np
import pinocchio as pin

from snac_gym.model.kinematics import Kinematics, PoseKinematics, shared_pose_kinematics
from snac_gym.references import PAPER_TARGET, Ellipse
from snac_gym.sampling import SampleSpace, nominal_configuration, sample_ellipse, sample_seed_pose
from snac_gym.tasks.base import CellReader, Task
from snac_gym.tasks.reach import TARGET_COLUMNS
from snac_gym.tasks.registry import TASKS, register_task
from snac_gym.tasks.track import ELLIPSE_COLUMNS, EllipseTrackTask

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

#: The tool pointing down (π about x), the orientation of the placeholder reference.
_DOWN = (np.pi, 0.0, 0.0)
#: Samples-CSV columns of the target orientation: the rotation vector log₃ R_d, rad, base frame.
ROTVEC_COLUMNS = ("rotvec_0", "rotvec_1", "rotvec_2")
#: The names of the pose tasks (known before they are registered: naming one registers them).
POSE_TASK_NAMES = ("pose-reach", "pose-track")
#: Reads and writes the ellipse columns of ``pose-track`` rows (the position task's codec).
_ELLIPSE_CODEC = EllipseTrackTask()


def _rotation_vector(value: Any, name: str) -> np.ndarray:
    vector = np.asarray(value, dtype=float)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise ValueError(f"{name} must be 3 finite numbers (a rotation vector, rad), got {value!r}")
    return vector


def _principal(rotation: Any) -> np.ndarray:
    """The rotation vector of the same rotation with norm ≤ π.

    One already inside the open ball ‖r‖ < π is kept as given: ``log₃(exp₃(r))`` moves it by up
    to 2e-11 rad, which would make a written and re-read sample differ from the one drawn.
    """
    vector = _rotation_vector(rotation, "rotation")
    return vector if np.linalg.norm(vector) < np.pi else pin.log3(pin.exp3(vector))


@dataclass(frozen=True)
class PoseTarget:
    """A fixed pose: ``x_d = [p_d; r_d]`` with ``r_d = log₃ R_d`` (m, rad), ``ẋ_d = 0``."""

    position: np.ndarray
    rotation: np.ndarray

    if TYPE_CHECKING:  # any 3 numbers each are taken (__post_init__ makes the arrays)

        def __init__(self, position: ArrayLike, rotation: ArrayLike) -> None: ...

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", _rotation_vector(self.position, "position"))
        object.__setattr__(self, "rotation", _principal(self.rotation))

    @property
    def centre(self) -> np.ndarray:
        return np.concatenate([self.position, self.rotation])

    def position_and_velocity(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self.centre, np.zeros(6)

    def trajectory(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        count = len(np.asarray(times))
        return np.tile(self.centre, (count, 1)), np.zeros((count, 6))

    def points(self, count: int = 1) -> np.ndarray:
        return self.centre[None, :]

    def to_dict(self) -> dict[str, Any]:
        return {"position": self.position.tolist(), "rotation": self.rotation.tolist()}


@dataclass(frozen=True)
class PoseEllipse:
    """An :class:`~snac_gym.references.Ellipse` for the position at a fixed orientation ``r_d`` (rad)."""

    ellipse: Ellipse
    rotation: np.ndarray

    if TYPE_CHECKING:  # any 3 numbers are taken for the rotation (__post_init__ makes the array)

        def __init__(self, ellipse: Ellipse, rotation: ArrayLike) -> None: ...

    def __post_init__(self) -> None:
        object.__setattr__(self, "rotation", _principal(self.rotation))

    @property
    def centre(self) -> np.ndarray:
        return np.concatenate([self.ellipse.centre, self.rotation])

    def position_and_velocity(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        position, velocity = self.ellipse.position_and_velocity(t)
        return np.concatenate([position, self.rotation]), np.concatenate([velocity, np.zeros(3)])

    def trajectory(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        positions, velocities = self.ellipse.trajectory(times)
        count = len(positions)
        return np.hstack([positions, np.tile(self.rotation, (count, 1))]), np.hstack([velocities, np.zeros((count, 3))])

    def points(self, count: int = 64) -> np.ndarray:
        positions = self.ellipse.points(count)
        return np.hstack([positions, np.tile(self.rotation, (len(positions), 1))])

    def to_dict(self) -> dict[str, Any]:
        return {**self.ellipse.to_dict(), "rotation": self.rotation.tolist()}


def check_pose_reachable(kinematics: PoseKinematics, poses: np.ndarray, what: str) -> None:
    """Raise ``ValueError`` naming the first of ``poses`` (rows ``[p; r]``) that pose IK does not reach."""
    q = kinematics.position.inverse_position(poses[0][:3], _nominal(kinematics))[0]
    for pose in poses:
        q, ok = kinematics.inverse_pose(pose, q)
        if not ok:
            raise ValueError(
                f"{what}: pose {np.round(pose, 4).tolist()} (m, rad) is not reachable by {kinematics.robot}"
            )


def pose_errors_and_jacobians(
    kinematics: PoseKinematics, qs: np.ndarray, x_d: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The pose errors of ``qs`` against ``x_d`` and their exact Jacobians ∂e/∂θ (the optimum's solver).

    ``e = [p − p_d; log₃(E)]`` with ``E = R R_dᵀ`` (:meth:`PoseKinematics.task_error`, row by row).
    A joint step turns R into ``exp(δφ) R`` with δφ = J_ω δθ (the base-frame angular rows), hence E
    into ``exp(δφ) E = E exp(Eᵀδφ)``, and ``δ log₃ E = Jlog₃(E) Eᵀ J_ω δθ``: unlike the controllers'
    J (which drops Jlog₃ → I near the target), this is the gradient of the cost actually scored.

    Args:
        kinematics: The pose kinematics.
        qs: ``(K, m)`` joint angles.
        x_d: ``(K, 6)`` desired poses ``[p_d; log₃ R_d]``.

    Returns:
        ``(errors, jacobians)`` of shapes ``(K, 6)`` and ``(K, 6, m)``.
    """
    poses, jacobians = kinematics.forward_and_jacobian_batch(qs)
    jacobians = jacobians.copy()  # the kinematics' remembered batch is read-only
    errors = np.empty(poses.shape)
    for k, (x, desired) in enumerate(zip(poses, x_d, strict=True)):
        errors[k] = kinematics.task_error(x, desired)
        relative = pin.exp3(x[3:]) @ pin.exp3(desired[3:]).T
        jacobians[k, 3:] = pin.Jlog3(relative) @ relative.T @ jacobians[k, 3:]
    return errors, jacobians


def is_pose_task(name: str) -> bool:
    """Whether ``name`` is one of the pose tasks (registered or not yet)."""
    return name in POSE_TASK_NAMES


def _nominal(kinematics: PoseKinematics) -> np.ndarray:
    return nominal_configuration(kinematics.position)


def _pose(kinematics: Kinematics | PoseKinematics) -> PoseKinematics:
    """The pose kinematics of the robot behind ``kinematics`` (position or pose)."""
    return kinematics if isinstance(kinematics, PoseKinematics) else shared_pose_kinematics(kinematics.robot)


class PoseReachTask(Task[PoseTarget | PoseEllipse]):
    """Reach a fixed pose (position and orientation); success ``‖e‖ ≤ 1e-3`` (1 mm, 1 mrad)."""

    name, label, code = "pose-reach", "Pose regulation", 10
    option_key = "pose"
    env_name = "PoseReach"
    csv_columns: ClassVar[tuple[str, ...]] = (*TARGET_COLUMNS, *ROTVEC_COLUMNS)
    success_tolerance = 1e-3
    episode_steps = 1500
    horizon_s = 12.0
    real_horizon_s = 15.0

    def make_kinematics(self, robot: str) -> PoseKinematics:
        return PoseKinematics(robot)

    def sample(
        self, kinematics: Kinematics | PoseKinematics, rng: np.random.Generator, space: SampleSpace
    ) -> PoseTarget | PoseEllipse:
        pose = _pose(kinematics)
        x = pose.forward(sample_seed_pose(pose.position, rng, space))
        return PoseTarget(x[:3], x[3:])

    def paper(self) -> PoseTarget | PoseEllipse:
        return PoseTarget(PAPER_TARGET, _DOWN)

    def scaled(self, reference: PoseTarget | PoseEllipse, factor: float) -> PoseTarget | PoseEllipse:
        if isinstance(reference, PoseEllipse):
            return PoseEllipse(reference.ellipse.scaled(factor), reference.rotation)
        return PoseTarget(reference.position * factor, reference.rotation)

    def parse(self, value: Any, kinematics: Kinematics | PoseKinematics) -> PoseTarget | PoseEllipse:
        target = value if isinstance(value, PoseTarget) else PoseTarget(value["position"], value["rotation"])
        check_pose_reachable(_pose(kinematics), target.points(), f"options[{self.option_key!r}]")
        return target

    def option_value(self, reference: PoseTarget | PoseEllipse) -> dict[str, Any]:
        return reference.to_dict()

    def csv_cells(self, reference: PoseTarget | PoseEllipse) -> dict[str, float]:
        # the task's own reference, a PoseTarget (the subclass PoseTrackTask has its own csv_cells)
        values = [*cast(PoseTarget, reference).position.tolist(), *reference.rotation.tolist()]
        return dict(zip(self.csv_columns, values, strict=True))

    def read_csv_reference(self, cells: CellReader) -> PoseTarget | PoseEllipse:
        return PoseTarget(cells.numbers(TARGET_COLUMNS), cells.numbers(ROTVEC_COLUMNS))

    def check_reference(
        self, kinematics: Kinematics | PoseKinematics, reference: PoseTarget | PoseEllipse, points: int, what: str
    ) -> None:
        """Raise ``ValueError`` unless pose IK reaches ``reference`` (``points`` poses of an ellipse).

        The samples CSV reader calls this instead of the position check, which cannot read a pose.
        """
        check_pose_reachable(_pose(kinematics), reference.points(points), what)


class PoseTrackTask(PoseReachTask):
    """Follow an ellipse with the tool at a fixed orientation; success: mean ‖e‖ over the 2nd half ≤ 5e-3."""

    name, label, code = "pose-track", "Pose tracking", 11
    option_key = "pose_ellipse"
    env_name = "PoseEllipseTrack"
    csv_columns = (*ELLIPSE_COLUMNS, *ROTVEC_COLUMNS)
    moving_reference = True
    success_tolerance = 5e-3
    success_measure = "mean_error_2nd_half"
    accuracy_measure = "median_error_2nd_half"
    accuracy_text = "median error over the second half"
    episode_steps = 2500
    horizon_s = 20.0
    real_horizon_s = 30.0

    def sample(
        self, kinematics: Kinematics | PoseKinematics, rng: np.random.Generator, space: SampleSpace
    ) -> PoseEllipse:
        pose = _pose(kinematics)
        for _ in range(200):
            ellipse = sample_ellipse(pose.position, rng, space)
            rotation = pose.forward(sample_seed_pose(pose.position, rng, space))[3:]
            candidate = PoseEllipse(ellipse, rotation)
            try:
                check_pose_reachable(pose, candidate.points(space.ellipse_points), "sample")
            except ValueError:
                continue
            return candidate
        raise RuntimeError(f"no ellipse reachable at a fixed orientation found in {space}")

    def paper(self) -> PoseEllipse:
        return PoseEllipse(Ellipse.paper_circle(), _DOWN)

    def parse(self, value: Any, kinematics: Kinematics | PoseKinematics) -> PoseEllipse:
        if not isinstance(value, PoseEllipse):
            spec = dict(value)
            rotation = spec.pop("rotation")
            value = PoseEllipse(Ellipse.from_dict(spec), rotation)
        reference: PoseEllipse = value
        check_pose_reachable(_pose(kinematics), reference.points(64), f"options[{self.option_key!r}]")
        return reference

    def csv_cells(self, reference: PoseTarget | PoseEllipse) -> dict[str, float]:
        rotation = dict(zip(ROTVEC_COLUMNS, reference.rotation.tolist(), strict=True))
        # the task's own reference, a PoseEllipse (PoseTarget in the signature: the base class's, PoseReachTask)
        return {**_ELLIPSE_CODEC.csv_cells(cast(PoseEllipse, reference).ellipse), **rotation}

    def read_csv_reference(self, cells: CellReader) -> PoseEllipse:
        return PoseEllipse(_ELLIPSE_CODEC.read_csv_reference(cells), cells.numbers(ROTVEC_COLUMNS))


#: The two pose tasks, one instance each (registering them again reuses their env classes).
POSE_TASKS: tuple[PoseReachTask, PoseTrackTask] = (PoseReachTask(), PoseTrackTask())


def register_pose_tasks() -> None:
    """Register the pose tasks (idempotent); their Gymnasium ids come with :func:`snac_gym.envs.register_pose_envs`."""
    for task in POSE_TASKS:
        if task.name not in TASKS:
            register_task(task)


__all__ = [
    "POSE_TASKS",
    "POSE_TASK_NAMES",
    "ROTVEC_COLUMNS",
    "PoseEllipse",
    "PoseReachTask",
    "PoseTarget",
    "PoseTrackTask",
    "check_pose_reachable",
    "is_pose_task",
    "pose_errors_and_jacobians",
    "register_pose_tasks",
]
