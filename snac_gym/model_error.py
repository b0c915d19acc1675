"""A wrong arm model: the kinematics a controller is given when it differs from the plant's.

Every real arm's model is off somewhere: a joint's zero is miscalibrated, a link is a little
longer than its drawing, the tool is mounted a few millimetres away from where the tool frame
says. :class:`ModelError` describes such an error in three parts,

* ``joint_offset = a₀, …, a_{m−1}`` (rad): the model reads joint j at θⱼ + aⱼ, i.e.
  f_model(θ) = f(θ + a);
* ``link_scale = s``: every fixed offset of the chain (the joint placements and the tool frame's)
  is (1 + s) times its true length;
* ``tool_offset = x, y, z`` (m): the model's tool point sits this far from the true one, in the
  tool frame;

and :meth:`ModelError.apply` writes it into a Pinocchio model, so that the erroneous kinematics is
an ordinary :class:`~snac_gym.kinematics.Kinematics` (``Kinematics(robot, model_error=...)``) with
the same batched paths. A joint offset enters the joint's placement, M_j · exp(aⱼ ωⱼ): rotations
about one axis commute, so M_j exp(aⱼ ωⱼ) exp(θⱼ ωⱼ) = M_j exp((θⱼ + aⱼ) ωⱼ).

The evaluator's ``--model-error SPEC`` gives the wrong model to the controllers, while the plant,
the cost and the success rule keep the true one (docs/model-error.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from snac_gym.validation import real_number

#: Pinocchio's joint-model letters → their axis.
_ALIGNED_AXES = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}


def joint_axis(joint_model: Any) -> tuple[np.ndarray, bool] | None:
    """The unit axis of a 1-DoF revolute or prismatic Pinocchio joint model and whether it is revolute (``None`` otherwise)."""
    kind = joint_model.shortname().removeprefix("JointModel")
    if kind in ("RX", "RY", "RZ", "PX", "PY", "PZ"):
        return np.array(_ALIGNED_AXES[kind[1]], dtype=float), kind[0] == "R"
    if kind in ("RevoluteUnaligned", "PrismaticUnaligned"):
        return np.array(joint_model.extract().axis, dtype=float).reshape(3), kind[0] == "R"
    return None


#: Largest relative link error a model may have (+100 %: every link twice its length).
MAX_LINK_SCALE = 1.0
#: Largest tool offset of a model in any axis, m.
MAX_TOOL_OFFSET = 1.0
#: The parts of a ``--model-error`` specification.
PARTS = ("joint_offset", "link_scale", "tool_offset")


@dataclass(frozen=True)
class ModelError:
    """How the controllers' arm model differs from the plant's (see the module docstring).

    Attributes:
        joint_offset: Per-joint offsets aⱼ, rad (empty: none).
        link_scale: Relative error s of every fixed link offset (0: none).
        tool_offset: Offset of the model's tool point in the tool frame, m.
    """

    joint_offset: tuple[float, ...] = ()
    link_scale: float = 0.0
    tool_offset: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        # Bounded to what a wrong model can be: a joint offset beyond ±π wraps round, a model link more than
        # twice its length or a tool a metre away is another arm (link_scale=1e6 used to be taken).
        for name, value in (("joint_offset", self.joint_offset), ("tool_offset", self.tool_offset)):
            if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
                raise ValueError(f"model error {name} must be a sequence of numbers, got {value!r}")
        offsets = tuple(real_number("model error joint_offset", a, -math.pi, math.pi) for a in self.joint_offset)
        if len(self.tool_offset) != 3:
            raise ValueError(f"model error tool_offset must be 3 finite numbers (x,y,z in m), got {list(self.tool_offset)}")
        tool = tuple(real_number("model error tool_offset (m)", t, -MAX_TOOL_OFFSET, MAX_TOOL_OFFSET) for t in self.tool_offset)
        scale = real_number("model error link_scale", self.link_scale, -1.0, MAX_LINK_SCALE, low_open=True)
        object.__setattr__(self, "joint_offset", offsets)
        object.__setattr__(self, "tool_offset", tool)
        object.__setattr__(self, "link_scale", scale)

    @classmethod
    def parse(cls, spec: str) -> ModelError:
        """``"joint_offset=0,0,0.3,0,0,0;link_scale=0.01;tool_offset=0,0,0.02"`` (parts separated by ``;``).

        Raises:
            ValueError: Naming the part that is wrong (an unknown name, a missing ``=``, a value
                that is not a number).
        """
        values: dict[str, Any] = {}
        for part in (p.strip() for p in str(spec).split(";")):
            if not part:
                continue
            name, sep, value = part.partition("=")
            name = name.strip()
            if not sep or name not in PARTS:
                raise ValueError(
                    f"--model-error: {part!r} is not NAME=VALUES with NAME one of {', '.join(PARTS)}"
                )
            if name in values:
                raise ValueError(f"--model-error: {name} is given twice")
            try:
                numbers = [float(v) for v in value.split(",")]
            except ValueError:
                raise ValueError(f"--model-error: {name}={value!r} is not a comma-separated list of numbers") from None
            if name == "link_scale":
                if len(numbers) != 1:
                    raise ValueError(f"--model-error: link_scale takes one number, got {value!r}")
                values[name] = numbers[0]
            else:
                values[name] = tuple(numbers)
        if not values:
            raise ValueError(f"--model-error: empty specification {spec!r}")
        try:
            return cls(**values)
        except ValueError as exc:
            raise ValueError(f"--model-error: {exc}") from None

    @property
    def is_zero(self) -> bool:
        """No error at all: the model is the plant's."""
        return not any(self.joint_offset) and self.link_scale == 0.0 and not any(self.tool_offset)

    def check_joints(self, n_joints: int) -> None:
        """Raise ``ValueError`` unless ``joint_offset`` is empty or has one value per joint."""
        if self.joint_offset and len(self.joint_offset) != n_joints:
            raise ValueError(
                f"--model-error: joint_offset needs {n_joints} values (one per joint), got {len(self.joint_offset)}"
            )

    def spec(self) -> str:
        """The ``--model-error`` text that parses back to this error (empty for no error)."""
        parts = []
        if any(self.joint_offset):
            parts.append("joint_offset=" + ",".join(repr(a) for a in self.joint_offset))
        if self.link_scale:
            parts.append(f"link_scale={self.link_scale!r}")
        if any(self.tool_offset):
            parts.append("tool_offset=" + ",".join(repr(t) for t in self.tool_offset))
        return ";".join(parts)

    def apply(self, model: Any, ee_frame_id: int) -> None:
        """Write the error into the Pinocchio ``model`` (in place; a model already rooted at its base).

        Joint offsets enter the joint placements (module docstring), the link scale every placement's
        translation and the tool frame's, the tool offset the tool frame's placement in its own axes.
        """
        self.check_joints(int(model.nq))
        for joint in range(1, model.njoints):
            placement = model.jointPlacements[joint]
            if self.link_scale:
                placement = pin.SE3(placement.rotation, (1.0 + self.link_scale) * placement.translation)
            index = int(model.joints[joint].idx_q)
            if self.joint_offset and self.joint_offset[index]:
                found = joint_axis(model.joints[joint])
                if found is None or not found[1]:
                    raise ValueError(f"a joint offset needs revolute joints; {model.names[joint]!r} is not one")
                axis = found[0]
                placement = placement * pin.SE3(pin.exp3(axis * self.joint_offset[index]), np.zeros(3))
            model.jointPlacements[joint] = placement
        frame = model.frames[ee_frame_id]
        placement = frame.placement
        if self.link_scale:
            placement = pin.SE3(placement.rotation, (1.0 + self.link_scale) * placement.translation)
        if any(self.tool_offset):
            placement = placement * pin.SE3(np.eye(3), np.asarray(self.tool_offset, dtype=float))
        frame.placement = placement
        model.frames[ee_frame_id] = frame


def refuse_pose_tasks(pose_tasks: Sequence[str]) -> None:
    """Refuse a model error on the pose tasks (the one refusal): the error family is written into the position
    kinematics (:class:`~snac_gym.kinematics.Kinematics`), not into the pose kinematics.

    Raises:
        ValueError: Naming the pose tasks, if any.
    """
    if pose_tasks:
        raise ValueError(f"--model-error applies to the position tasks; not to {', '.join(pose_tasks)}")


def parse_model_error(spec: str | ModelError | None) -> ModelError | None:
    """``None`` or a zero error for no error; a :class:`ModelError` from its text otherwise."""
    if spec is None or isinstance(spec, ModelError):
        return spec
    return ModelError.parse(spec)


__all__ = ["PARTS", "ModelError", "parse_model_error"]
