"""The task contract: everything that differs between reaching a point and tracking a path.

A :class:`Task` is the only place that names a task. It owns how a reference is drawn, pinned
and parsed (env ``reset`` options and the evaluator's CSV columns), the paper's reference and
demo, the success rule and its tolerance, and the default horizons. The envs, the evaluator,
the demo, PPO and the real-robot run all ask the task; adding one is a new module that
subclasses :class:`Task` plus one :func:`snac_gym.tasks.register_task` call.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Generic, Protocol, TypeVar

import numpy as np
import numpy.typing as npt

from snac_gym.model.kinematics import Kinematics, PoseKinematics, shared_kinematics
from snac_gym.model.robots import get_robot
from snac_gym.references import PAPER_Q0, Reference
from snac_gym.sampling import SampleSpace, reach_scale
from snac_gym.tasks.registry import get_task

#: The type of a task's references (a :class:`Task` subclass names its own: ``Task[FixedTarget]``).
_ReferenceT = TypeVar("_ReferenceT")


class CellReader(Protocol):
    """Typed access to one row of a samples CSV (see :mod:`snac_gym.evaluation.samples`)."""

    def number(self, column: str, default: float | None = None) -> float:
        """The cell as a finite float (``default`` when empty); raises naming the row and column."""

    def numbers(self, columns: Sequence[str]) -> np.ndarray:
        """Several required cells as floats."""

    def error(self, column: str, message: str) -> ValueError:
        """An error naming the row and ``column``."""


class Task(ABC, Generic[_ReferenceT]):
    """A named reference family (subclass it; see :mod:`snac_gym.tasks.reach` for a small one): a subclass
    implements the six abstract methods (references drawn, the paper's, parsed, written back, and the CSV's).

    Class attributes:
        name: The task's name (``--task``, the ``task`` column of every results file).
        label: Its name in tables (the paper's Table I rows).
        code: Spawn-key code of its random samples; fixed forever, since changing it changes
            every sample set drawn with it.
        option_key: The env ``reset`` option that pins its reference.
        env_name: The task's part of its Gymnasium ids: ``Reach`` in ``snac_gym/PandaReach-v0``
            (one id per registered robot, :meth:`env_id_for`).
        env_version: The version of :meth:`env_id_for`'s ids (``-v0``; every id also has a ``-v1``,
            the RL-ready defaults, registered beside it).
        moving_reference: Whether x_d moves (tracking): the policies then see ẋ_d ≠ 0.
        success_tolerance: Success threshold on the error norm, m.
        success_measure: What the success rule reads: ``"final_error"`` (‖e_K‖) or
            ``"mean_error_2nd_half"`` (mean ‖eₖ‖ over the second half of the steps).
        accuracy_measure: The accuracy a table shows beside the cost (a column of the
            evaluator's results).
        accuracy_text: That accuracy in words.
        episode_steps: Default episode length of the env, control steps at 125 Hz.
        horizon_s: Default horizon of the demo and the evaluator, s.
        real_horizon_s: Default episode of ``snac-gym real``, s: longer than the demo's, since
            the conservative speed scale of the safety layer slows the arm down.
        csv_columns: The columns of the evaluator's samples CSV that hold its reference.
    """

    name: ClassVar[str]
    label: ClassVar[str]
    code: ClassVar[int]
    option_key: ClassVar[str]
    env_name: ClassVar[str]
    env_version: ClassVar[int] = 0
    moving_reference: ClassVar[bool] = False
    success_tolerance: ClassVar[float]
    success_measure: ClassVar[str] = "final_error"
    accuracy_measure: ClassVar[str] = "final_error"
    accuracy_text: ClassVar[str] = "final error"
    episode_steps: ClassVar[int]
    horizon_s: ClassVar[float]
    real_horizon_s: ClassVar[float]
    csv_columns: ClassVar[tuple[str, ...]] = ()

    # -- Gymnasium ids ---------------------------------------------------------------------
    def env_id_for(self, robot: str = "ur10", goal: bool = False, version: int | None = None) -> str:
        """The task's id on ``robot``: ``snac_gym/<Robot><env_name>[Goal]-v<version>``.

        Args:
            robot: A registered robot (its :attr:`~snac_gym.model.robots.Robot.env_prefix` names it).
            goal: The goal-conditioned variant (:mod:`snac_gym.envs.goal`).
            version: The id's version (default :attr:`env_version`, 0: physical units, the id the evaluator,
                the demo and the benchmarks use); 1 gives the RL-ready id (docs/environments.md, "v1 vs v0").
        """
        suffix = "Goal" if goal else ""
        version = self.env_version if version is None else int(version)
        return f"snac_gym/{get_robot(robot).env_prefix}{self.env_name}{suffix}-v{version}"

    @property
    def env_id(self) -> str:
        """The task's id on the UR10, the paper's arm (``snac_gym/UR10Reach-v0``)."""
        return self.env_id_for("ur10")

    # -- kinematics --------------------------------------------------------------------------
    def make_kinematics(self, robot: str) -> Kinematics | PoseKinematics:
        """The kinematics of the task's coordinates on ``robot`` (the envs build theirs here): the
        end-effector position (:class:`Kinematics`, task_dim 3); a pose task returns a
        :class:`~snac_gym.model.kinematics.PoseKinematics` (task_dim 6, its own ``task_error``)."""
        return Kinematics(robot)

    # -- references ------------------------------------------------------------------------
    @abstractmethod
    def sample(self, kinematics: Kinematics, rng: np.random.Generator, space: SampleSpace) -> _ReferenceT:
        """A random reference from ``space``, drawn from ``rng`` (the envs' and the evaluator's)."""

    @abstractmethod
    def paper(self) -> _ReferenceT:
        """The paper's reference for this task."""

    @abstractmethod
    def parse(self, value: Any, kinematics: Kinematics) -> _ReferenceT:
        """The reference of the reset option ``value``, checked to be reachable.

        Raises:
            ValueError: If it is malformed or unreachable.
        """

    @abstractmethod
    def option_value(self, reference: _ReferenceT) -> object:
        """The reset-option value (JSON types) that :meth:`parse` turns back into ``reference``."""

    def reset_options(self, q0: Sequence[float] | np.ndarray, reference: _ReferenceT) -> dict[str, Any]:
        """Env ``reset`` options that pin the start pose and the reference."""
        return {"q0": [float(v) for v in q0], self.option_key: self.option_value(reference)}

    def scaled(self, reference: _ReferenceT, factor: float) -> _ReferenceT:
        """``reference`` for an arm ``factor`` times the UR10's size: its positions scaled about the base, its
        orientations and angular speeds kept. The base class keeps ``reference`` as it is (a task whose reference
        has no such scaling)."""
        return reference

    def demo_options(self, robot: str | None = None) -> dict[str, Any]:
        """Reset options of the demonstration on ``robot``.

        The start pose and reference of the robot's registered ``demo_options`` (:mod:`snac_gym.model.robots`,
        the 7-DOF arms), else the paper's θ₀ of Section V and the paper's reference (``robot=None``: the UR10's),
        the reference :meth:`scaled` to the arm by :func:`~snac_gym.sampling.reach_scale` as the evaluator's
        cuboid is (the UR3 and UR5 do not reach the paper's numbers; the UR5e reaches its target at the edge of
        its reach).

        Raises:
            ValueError: If the robot's demo names no reference for this task.
        """
        own = None if robot is None else get_robot(robot).demo_options
        if own is None:
            factor = 1.0 if robot is None else reach_scale(shared_kinematics(robot))
            paper = self.paper()
            # The UR10 (its reach is given to 6 digits): the paper's numbers as printed.
            return self.reset_options(PAPER_Q0, paper if abs(factor - 1.0) < 1e-6 else self.scaled(paper, factor))
        if self.name not in own:
            raise ValueError(f"robot {robot!r} has no {self.name} demo; it has {sorted(k for k in own if k != 'q0')}")
        return {"q0": [float(v) for v in own["q0"]], self.option_key: own[self.name]}

    def horizon_steps(self, dt: float) -> int:
        """Control steps of the default horizon at period ``dt``."""
        return round(self.horizon_s / dt)

    # -- samples CSV -------------------------------------------------------------------------
    @abstractmethod
    def csv_cells(self, reference: _ReferenceT) -> dict[str, float]:
        """The values of :attr:`csv_columns` for ``reference``."""

    @abstractmethod
    def read_csv_reference(self, cells: CellReader) -> _ReferenceT:
        """The reference of one CSV row (unreachability is checked by the caller).

        Raises:
            ValueError: From ``cells.error`` naming the offending column.
        """

    def csv_reference_span(self) -> str:
        """The columns an unreachable reference is reported against, e.g. ``"target_0..target_2"``."""
        return f"{self.csv_columns[0]}..{self.csv_columns[-1]}"

    # -- success -----------------------------------------------------------------------------
    def success(
        self, measures: Mapping[str, Any], tolerance: float | None = None
    ) -> bool | np.bool_ | npt.NDArray[np.bool_]:
        """Whether each rollout succeeded: ``measures[success_measure] <= tolerance``.

        Args:
            measures: At least :attr:`success_measure` (a float or an array of them), m.
            tolerance: The threshold (default :attr:`success_tolerance`), m.
        """
        threshold = self.success_tolerance if tolerance is None else tolerance
        passed: bool | np.bool_ | npt.NDArray[np.bool_] = measures[self.success_measure] <= threshold
        return passed

    def success_text(self, tolerance: float | None = None) -> str:
        """The success rule in words, for reports and figure titles."""
        threshold = self.success_tolerance if tolerance is None else tolerance
        what = "final ‖e‖" if self.success_measure == "final_error" else "mean ‖e‖ over the 2nd half"
        return f"{what} ≤ {threshold * 1e3:g} mm"

    def __repr__(self) -> str:
        return f"<Task {self.name!r}>"

    def __reduce__(self) -> tuple[Any, ...]:
        # Tasks are registry singletons: unpickling (worker processes, Ray) returns the registered one.
        return get_task, (self.name,)


@dataclass(frozen=True)
class Sample:
    """Where one rollout starts and what it must reach or follow.

    Attributes:
        task: The task's name.
        index: Sample id, unique within the task.
        q0: Start joint pose θ₀, rad.
        reference: The task's reference (a fixed target, an ellipse).
    """

    task: str
    index: int
    q0: np.ndarray
    reference: Reference

    def reset_options(self) -> dict[str, Any]:
        """The env ``reset`` options that pin this sample (``q0`` and the task's reference key)."""
        task: Task[Any] = get_task(self.task)  # Any: the registry holds tasks of every reference type
        return task.reset_options(self.q0, self.reference)
