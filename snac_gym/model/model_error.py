"""A wrong arm model: the kinematics a controller is given when it differs from the plant's.

Every real arm's model is off somewhere: a joint's zero is miscalibrated, a link is a little
longer than its drawing, a joint axis is tilted, the base stands a few millimetres from where it is
believed to, the tool is mounted off its frame. :class:`ModelError` describes such an error in
parts, any of them combined (m joints; "placement j" is joint j's fixed placement M_j = (R_j, t_j)
in its parent's frame, in configuration order, in the model that
:class:`~snac_gym.model.kinematics.Kinematics` has re-rooted at the base frame, so a root joint's
translation is measured from the base frame's origin):

* ``joint_offset = a₀, …, a_{m−1}`` (rad): the model reads joint j at θⱼ + aⱼ, i.e.
  f_model(θ) = f(θ + a);
* ``link_scale = s``: every fixed offset of the chain (the joint placements and the tool frame's)
  is (1 + s) times its true length;
* ``link_length = d₀, …, d_{m−1}`` (m): placement j's translation keeps its direction and has length
  ‖t_j‖ + d_j (after ``link_scale``); a nonzero d_j for a zero-length placement is refused (it has
  no direction), as is a d_j that makes the length zero or negative; |d_j| ≤ 0.5 m;
* ``joint_axis_tilt = α₀, …, α_{m−1}[, β₀, …, β_{m−1}]`` (rad; m or 2m values): joint j's frame is
  rotated, M_j ← M_j · exp(α_j u_j + β_j v_j) (β_j = 0 with m values), so the joint axis and the
  chain after it are tilted by √(α_j² + β_j²) (an MDH-α-like error). With ω_j the joint's unit axis in
  its own frame and e_k the frame's basis vector least aligned with it (the smallest |ω_j,k|, the
  first such k on a tie), u_j = (ω_j × e_k)/‖ω_j × e_k‖ and v_j = ω_j × u_j: two unit vectors
  perpendicular to ω_j and to each other (for an axis z: u = y, v = −x; for y: u = −z, v = −x);
  |α_j|, |β_j| ≤ 0.5 rad;
* ``base = x, y, z, rx, ry, rz`` (m, rad): the model believes the arm's base is displaced by
  T = SE3(exp₃(r), t): f_model(θ) = T · f(θ) (T multiplies every joint placement and frame that
  hangs from the base); |x|, |y|, |z| ≤ 1 m, ‖r‖ ≤ π;
* ``tool_offset = x, y, z`` (m): the model's tool point sits this far from the true one, in the
  tool frame;
* ``random = σ, seed``: a random rigid error of every placement and of the tool frame. numpy's
  ``default_rng(seed).standard_normal((n + 1, 6))`` times σ gives, row j for placement j (Pinocchio's
  joint order, n placements) and the last row for the tool frame, a translation τ (the first three
  columns, m) and a rotation vector ρ (the last three, rad), applied as M ← M · SE3(exp₃(ρ), τ). The
  draw depends on σ, the seed and n only, and scales with σ (the same seed at 2σ is twice the
  error). 0 ≤ σ ≤ 0.1; the seed is a non-negative integer;
* ``model = NAME``: the controllers get another registered robot's kinematics
  (:mod:`snac_gym.model.robots`, e.g. ``model=ur5`` for a UR10), with the same joint count; the other
  parts apply on top of that robot. :meth:`Kinematics.with_model_error
  <snac_gym.model.kinematics.Kinematics.with_model_error>` is the builder that honours it;
  :meth:`ModelError.apply` ignores it.

What the family represents: ``random`` perturbs every fixed transform of a serial chain (each joint
placement and the tool frame) by an arbitrary small rigid motion, which is every rigid geometric
error such a chain can have (a joint's zero offset is a rotation about its axis at the end of its
placement, a base error one of the first placement); the named parts are the common special cases,
with sizes one can state. What it cannot represent: a joint's gear-ratio (scale) error, compliance
(links or gears bending under load), backlash, thermal drift or any other non-rigid or
configuration-dependent effect; nor an error of the joint *type* or count.

Per placement the parts compose as M_j ← T_base · (R_j, t̃_j) · E_j · exp(α_j u_j + β_j v_j) · exp(a_j ω_j)
(T_base for a root joint only, t̃_j the translation after ``link_scale`` and ``link_length``, E_j the
random draw), and for the tool frame as M ← (R, (1 + s) t) · E_tool · (I, tool offset). A joint offset
enters last, next to the joint's motion: rotations about one axis commute, so
M_j exp(aⱼ ωⱼ) exp(θⱼ ωⱼ) = M_j exp((θⱼ + aⱼ) ωⱼ). :meth:`ModelError.apply` writes the error into a
Pinocchio model, so the erroneous kinematics is an ordinary :class:`~snac_gym.model.kinematics.Kinematics`
with the same batched paths.

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

from snac_gym.common.validation import real_number, whole_number
from snac_gym.model.robots import get_robot

#: Pinocchio's joint-model letters → their axis.
_ALIGNED_AXES = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}


def joint_axis(joint_model: Any) -> tuple[np.ndarray, bool] | None:
    """The unit axis of a 1-DoF revolute or prismatic Pinocchio joint model and whether it is revolute (``None``
    otherwise)."""
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
#: Largest change of one placement's length, m.
MAX_LINK_LENGTH = 0.5
#: Largest tilt of a joint axis in either direction, rad.
MAX_AXIS_TILT = 0.5
#: Largest base displacement in any axis, m.
MAX_BASE_OFFSET = 1.0
#: Largest standard deviation of the random error, m and rad.
MAX_RANDOM_SIGMA = 0.1
#: Largest seed of the random error.
MAX_RANDOM_SEED = 2**63 - 1
#: The parts of a ``--model-error`` specification.
PARTS = ("joint_offset", "link_scale", "tool_offset", "link_length", "joint_axis_tilt", "base", "random", "model")
#: Below this a placement has no length (and no direction to lengthen it along), m.
_ZERO_LENGTH = 1e-12


def _numbers(name: str, value: Any) -> tuple[Any, ...]:
    if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
        raise ValueError(f"model error {name} must be a sequence of numbers, got {value!r}")
    return tuple(value)


def tilt_directions(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(u, v)`` of a joint axis ω (module docstring): u = ω × e_k / ‖ω × e_k‖ for the basis vector e_k least
    aligned with ω (the first on a tie), v = ω × u."""
    axis = np.asarray(axis, dtype=float)
    least = int(np.argmin(np.abs(axis)))
    u = np.cross(axis, np.eye(3)[least])
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


@dataclass(frozen=True)
class ModelError:
    """How the controllers' arm model differs from the plant's (see the module docstring).

    Attributes:
        joint_offset: Per-joint offsets aⱼ, rad (empty: none).
        link_scale: Relative error s of every fixed link offset (0: none).
        tool_offset: Offset of the model's tool point in the tool frame, m.
        link_length: Per-joint change d_j of the placement's length, m (empty: none).
        joint_axis_tilt: Per-joint tilts α_j (m values) or α_j then β_j (2m values), rad (empty: none).
        base: The model's base displacement (x, y, z, rx, ry, rz), m and rad (rotation vector).
        random: ``(σ, seed)`` of the random rigid error of every placement and the tool frame (``None``: none).
        model: A registered robot whose kinematics the model is (``None``: the arm's own); honoured by
            :meth:`Kinematics.with_model_error <snac_gym.model.kinematics.Kinematics.with_model_error>`.
    """

    joint_offset: tuple[float, ...] = ()
    link_scale: float = 0.0
    tool_offset: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0))
    link_length: tuple[float, ...] = ()
    joint_axis_tilt: tuple[float, ...] = ()
    base: tuple[float, float, float, float, float, float] = field(default=(0.0,) * 6)
    random: tuple[float, int] | None = None
    model: str | None = None

    def __post_init__(self) -> None:
        # Bounded to what a wrong model can be: a joint offset beyond ±π wraps round, a model link more than
        # twice its length or a tool a metre away is another arm.
        for name in ("joint_offset", "tool_offset", "link_length", "joint_axis_tilt", "base"):
            _numbers(name, getattr(self, name))
        offsets = tuple(real_number("model error joint_offset", a, -math.pi, math.pi) for a in self.joint_offset)
        if len(self.tool_offset) != 3:
            raise ValueError(
                f"model error tool_offset must be 3 finite numbers (x,y,z in m), got {list(self.tool_offset)}"
            )
        tool = tuple(
            real_number("model error tool_offset (m)", t, -MAX_TOOL_OFFSET, MAX_TOOL_OFFSET) for t in self.tool_offset
        )
        scale = real_number("model error link_scale", self.link_scale, -1.0, MAX_LINK_SCALE, low_open=True)
        lengths = tuple(
            real_number("model error link_length (m)", d, -MAX_LINK_LENGTH, MAX_LINK_LENGTH) for d in self.link_length
        )
        tilts = tuple(
            real_number("model error joint_axis_tilt (rad)", a, -MAX_AXIS_TILT, MAX_AXIS_TILT)
            for a in self.joint_axis_tilt
        )
        if len(self.base) != 6:
            raise ValueError(
                f"model error base must be 6 finite numbers (x,y,z in m, rx,ry,rz in rad), got {list(self.base)}"
            )
        base = tuple(
            real_number("model error base x,y,z (m)", b, -MAX_BASE_OFFSET, MAX_BASE_OFFSET) for b in self.base[:3]
        ) + tuple(real_number("model error base rx,ry,rz (rad)", b, -math.pi, math.pi) for b in self.base[3:])
        if np.linalg.norm(base[3:]) > math.pi:
            raise ValueError(
                f"model error base rotation vector rx,ry,rz must have a norm of at most pi, got {list(base[3:])}"
            )
        object.__setattr__(self, "joint_offset", offsets)
        object.__setattr__(self, "tool_offset", tool)
        object.__setattr__(self, "link_scale", scale)
        object.__setattr__(self, "link_length", lengths)
        object.__setattr__(self, "joint_axis_tilt", tilts)
        object.__setattr__(self, "base", base)
        object.__setattr__(self, "random", self._checked_random())
        object.__setattr__(self, "model", self._checked_model())

    def _checked_random(self) -> tuple[float, int] | None:
        if self.random is None:
            return None
        values = _numbers("random", self.random)
        if len(values) != 2:
            raise ValueError(f"model error random must be 2 numbers (sigma, seed), got {list(values)}")
        sigma = real_number("model error random sigma", values[0], 0.0, MAX_RANDOM_SIGMA)
        seed = whole_number("model error random seed", values[1], 0, MAX_RANDOM_SEED)
        return sigma, seed

    def _checked_model(self) -> str | None:
        if self.model is None:
            return None
        if not isinstance(self.model, str) or not self.model.strip():
            raise ValueError(f"model error model must name a registered robot, got {self.model!r}")
        try:
            return get_robot(self.model.strip()).name
        except ValueError as exc:
            raise ValueError(f"model error model: {exc}") from None

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
                raise ValueError(f"--model-error: {part!r} is not NAME=VALUES with NAME one of {', '.join(PARTS)}")
            if name in values:
                raise ValueError(f"--model-error: {name} is given twice")
            values[name] = _part_value(name, value)
        if not values:
            raise ValueError(f"--model-error: empty specification {spec!r}")
        try:
            return cls(**values)
        except ValueError as exc:
            raise ValueError(f"--model-error: {exc}") from None

    @property
    def is_zero(self) -> bool:
        """No error at all: the model is the plant's."""
        return (
            not any(self.joint_offset) and self.link_scale == 0.0 and not any(self.tool_offset)
            and not any(self.link_length) and not any(self.joint_axis_tilt) and not any(self.base)
            and (self.random is None or self.random[0] == 0.0) and self.model is None
        )  # fmt: skip

    def check_joints(self, n_joints: int) -> None:
        """Raise ``ValueError`` unless each per-joint part is empty or has one value per joint (``joint_axis_tilt``:
        one or two per joint)."""
        for name in ("joint_offset", "link_length"):
            count = len(getattr(self, name))
            if count and count != n_joints:
                raise ValueError(f"--model-error: {name} needs {n_joints} values (one per joint), got {count}")
        count = len(self.joint_axis_tilt)
        if count and count not in (n_joints, 2 * n_joints):
            raise ValueError(
                f"--model-error: joint_axis_tilt needs {n_joints} values (one per joint) or {2 * n_joints} "
                f"(two per joint), got {count}"
            )

    def spec(self) -> str:
        """The ``--model-error`` text that parses back to this error (empty for no error)."""
        parts = []
        if any(self.joint_offset):
            parts.append("joint_offset=" + ",".join(repr(a) for a in self.joint_offset))
        if self.link_scale:
            parts.append(f"link_scale={self.link_scale!r}")
        for name in ("link_length", "joint_axis_tilt", "base", "tool_offset"):
            if any(getattr(self, name)):
                parts.append(f"{name}=" + ",".join(repr(v) for v in getattr(self, name)))
        if self.random is not None and self.random[0]:
            parts.append(f"random={self.random[0]!r},{self.random[1]}")
        if self.model is not None:
            parts.append(f"model={self.model}")
        return ";".join(parts)

    def random_draws(self, n_placements: int) -> np.ndarray:
        """The random error's rows ``(τ, ρ)``, shape ``(n_placements + 1, 6)`` (the tool frame's last; zeros without
        one)."""
        if self.random is None or not self.random[0]:
            return np.zeros((n_placements + 1, 6))
        sigma, seed = self.random
        return sigma * np.random.default_rng(seed).standard_normal((n_placements + 1, 6))

    def apply(self, model: Any, ee_frame_id: int) -> None:
        """Write the error into the Pinocchio ``model`` (in place; a model already rooted at its base), as the
        module docstring composes it. ``model`` (another robot) is not applied here:
        :meth:`Kinematics.with_model_error <snac_gym.model.kinematics.Kinematics.with_model_error>` builds that robot.

        Raises:
            ValueError: For a per-joint part of the wrong count, a joint offset of a joint that is not revolute, a
                length change of a zero-length placement or one that leaves no length, naming the joint.
        """
        self.check_joints(int(model.nq))
        draws = self.random_draws(model.njoints - 1)
        tilts = np.zeros((2, int(model.nq)))
        tilts.reshape(-1)[: len(self.joint_axis_tilt)] = self.joint_axis_tilt
        base = pin.SE3(pin.exp3(np.asarray(self.base[3:])), np.asarray(self.base[:3])) if any(self.base) else None
        for joint in range(1, model.njoints):
            placement = self._placement(model, joint, draws[joint - 1], tilts)
            model.jointPlacements[joint] = (
                base * placement if base is not None and model.parents[joint] == 0 else placement
            )
        frame = model.frames[ee_frame_id]
        placement = frame.placement
        if self.link_scale:
            placement = pin.SE3(placement.rotation, (1.0 + self.link_scale) * placement.translation)
        if draws[-1].any():
            placement = placement * pin.SE3(pin.exp3(draws[-1, 3:]), draws[-1, :3])
        if any(self.tool_offset):
            placement = placement * pin.SE3(np.eye(3), np.asarray(self.tool_offset, dtype=float))
        frame.placement = placement
        model.frames[ee_frame_id] = frame
        if base is not None:
            for frame in model.frames:
                if frame.parentJoint == 0:
                    frame.placement = base * frame.placement

    def _placement(self, model: Any, joint: int, draw: np.ndarray, tilts: np.ndarray) -> Any:
        """Joint ``joint``'s placement with every part but the base applied (module docstring)."""
        placement = model.jointPlacements[joint]
        index = int(model.joints[joint].idx_q)
        name = model.names[joint]
        translation = (1.0 + self.link_scale) * placement.translation
        if self.link_length and self.link_length[index]:
            translation = _lengthened(translation, self.link_length[index], name)
        placement = pin.SE3(placement.rotation, translation)
        if draw.any():
            placement = placement * pin.SE3(pin.exp3(draw[3:]), draw[:3])
        found = joint_axis(model.joints[joint])
        if tilts[:, index].any():
            if found is None:
                raise ValueError(f"model error joint_axis_tilt needs 1-DoF joints; {name!r} is not one")
            u, v = tilt_directions(found[0])
            placement = placement * pin.SE3(pin.exp3(tilts[0, index] * u + tilts[1, index] * v), np.zeros(3))
        if self.joint_offset and self.joint_offset[index]:
            if found is None or not found[1]:
                raise ValueError(f"a joint offset needs revolute joints; {name!r} is not one")
            placement = placement * pin.SE3(pin.exp3(found[0] * self.joint_offset[index]), np.zeros(3))
        return placement


def _part_value(name: str, value: str) -> Any:
    """The value of one ``NAME=VALUES`` part: a robot name for ``model``, a number for ``link_scale``, numbers
    otherwise."""
    if name == "model":
        return value.strip()
    try:
        numbers = [_parse_number(v) if name == "random" else float(v) for v in value.split(",")]
    except ValueError:
        raise ValueError(f"--model-error: {name}={value!r} is not a comma-separated list of numbers") from None
    if name == "link_scale":
        if len(numbers) != 1:
            raise ValueError(f"--model-error: link_scale takes one number, got {value!r}")
        return numbers[0]
    return tuple(numbers)


def _parse_number(text: str) -> float | int:
    """An integer as an int (a seed keeps every digit), anything else as a float."""
    try:
        return int(text)
    except ValueError:
        return float(text)


def _lengthened(translation: np.ndarray, change: float, joint: str) -> np.ndarray:
    """``translation`` with its length changed by ``change`` along its own direction."""
    length = float(np.linalg.norm(translation))
    if length < _ZERO_LENGTH:
        raise ValueError(
            f"model error link_length: joint {joint!r} has a zero-length placement, so its change must be 0, "
            f"got {change!r}"
        )
    if length + change <= 0.0:
        raise ValueError(
            f"model error link_length: {change!r} m leaves no length to the placement of joint {joint!r} "
            f"({length:.6g} m long)"
        )
    return translation * ((length + change) / length)


def tool_displacement(true_kinematics: Any, model_kinematics: Any, qs: np.ndarray) -> np.ndarray:
    """‖f_true(θ) − f_model(θ)‖ for each row θ of ``qs`` ``(B, m)``, m: how far the model puts the tool point.

    Both are :class:`~snac_gym.model.kinematics.Kinematics` (anything with ``n_joints`` and ``forward_batch``) of the
    same joint count, e.g. a robot's and its ``with_model_error(...)``.

    Raises:
        ValueError: If the joint counts differ.
    """
    if true_kinematics.n_joints != model_kinematics.n_joints:
        raise ValueError(
            f"tool_displacement needs the same joint count, got {true_kinematics.n_joints} and "
            f"{model_kinematics.n_joints}"
        )
    qs = np.asarray(qs, dtype=float)
    displacement: np.ndarray = np.linalg.norm(
        np.asarray(true_kinematics.forward_batch(qs)) - np.asarray(model_kinematics.forward_batch(qs)), axis=1
    )
    return displacement


def refuse_pose_tasks(pose_tasks: Sequence[str]) -> None:
    """Refuse a model error on the pose tasks (the one refusal): the error family is written into the position
    kinematics (:class:`~snac_gym.model.kinematics.Kinematics`), not into the pose kinematics.

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


__all__ = ["PARTS", "ModelError", "parse_model_error", "tilt_directions", "tool_displacement"]
