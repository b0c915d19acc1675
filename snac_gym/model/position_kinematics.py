"""The position kinematics of a serial arm (:class:`Kinematics`, the project's one source of f(θ) and J(θ);
:mod:`snac_gym.model.kinematics`), and the joint integration and damped least squares every caller shares."""

from __future__ import annotations

import dataclasses
import math
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from snac_gym.kernels.compiled import read_only_view
from snac_gym.model.chains import BatchChain
from snac_gym.model.model_error import ModelError, parse_model_error
from snac_gym.model.robots import get_robot, robot_names
from snac_gym.model.urdf import robot_urdf_path

__all__ = ["Kinematics", "damped_least_squares", "damped_resolve_rows", "joint_path", "joint_step", "shared_kinematics"]


def joint_step(q: np.ndarray, u: np.ndarray, dt: float, out: np.ndarray | None = None) -> np.ndarray:
    """The paper's kinematic model over one control period, exactly: θₖ₊₁ = θₖ + uₖΔt (eq. 3).

    The one implementation of the step: the kinematic arm of the single env
    (:class:`~snac_gym.physics.KinematicArm`), the batched vector env
    (:class:`~snac_gym.envs.vector.KinematicEpisodes`) and the evaluator's lockstep engine
    (:func:`~snac_gym.rollout.simulate_kinematic`) all call it, so the three agree bit for bit; the UR
    controller emulator's arm (``snac_gym.real.emulator.arm.EmulatedArm``) integrates its motion with it too.

    Args:
        q: Joint positions θₖ, rad: ``(m,)`` or a batch ``(B, m)``.
        u: Joint velocities uₖ held over the period, rad/s, the same shape.
        dt: Control period Δt, s.
        out: Where to write θₖ₊₁ (may be ``q`` itself); a new array when ``None``.

    Returns:
        θₖ₊₁ (``out`` when given).
    """
    q_next: np.ndarray = np.add(q, u * dt, out=out)
    return q_next


def joint_path(q0: np.ndarray, commands: np.ndarray, dt: float) -> np.ndarray:
    """θ₁..θ_K of the same model over a command sequence ``(K, m)`` at once: θₖ₊₁ = θ₀ + Δt Σᵢ≤ₖ uᵢ (eq. 3).

    The trajectory optimiser's form (:mod:`snac_gym.control.trajopt`): a cumulative sum, which rounds differently
    from K calls of :func:`joint_step` (about 1e-13 rad over 2500 steps; hence its limit clearance). Compiled
    (:func:`snac_gym.kernels.trajopt.joint_path`): ``q0 + cumsum(commands, axis=0) * dt`` bit for bit.
    """
    from snac_gym.kernels.trajopt import joint_path as compiled_path  # numba: imported where first needed

    path: np.ndarray = compiled_path(read_only_view(q0), read_only_view(commands), float(dt))
    return path


def damped_least_squares(jacobian: np.ndarray, task_velocity: np.ndarray, damping_matrix: np.ndarray) -> np.ndarray:
    """``Jᵀ(JJᵀ + λ²I)⁻¹ v``: the joint velocity of least ``‖Ju − v‖² + λ²‖u‖²`` (damped least squares).

    One ``J`` ``(n, m)`` with ``v`` ``(n,)``, or stacks ``(B, n, m)`` with ``(B, n, 1)``;
    ``damping_matrix`` is ``λ²I`` ``(n, n)``. The map of the ``dls`` controller, the PPO policies'
    task-space action and the goal envs' Cartesian action.
    """
    jacobian_t = jacobian.T if jacobian.ndim <= 2 else np.swapaxes(jacobian, -1, -2)
    return jacobian_t @ np.linalg.solve(jacobian @ jacobian_t + damping_matrix, task_velocity)


def damped_resolve_rows(jacobians: np.ndarray, velocities: np.ndarray, damping: float) -> np.ndarray:
    """:func:`damped_least_squares`'s ``Jᵀ(JJᵀ + λ²I)⁻¹ v``, compiled, for one ``J`` ``(n, m)`` and ``v`` ``(n,)`` or
    stacks ``(B, n, m)``, ``(B, n)``; ``damping`` is λ.

    The same to rounding (a Cholesky solve of each n×n system: :func:`~snac_gym.kernels.small.damped_resolve`), at a
    fraction of the cost on stacks (NumPy's batched ``solve`` spends most of its time per 3×3 matrix); one row goes
    as a stack of one, so a row of a stack is bit for bit the row alone. The map of the ``dls`` controller's, the PPO
    policies' and the joint-goal IK's steps.
    """
    from snac_gym.kernels.small import damped_resolve  # numba: imported where first needed

    jac = np.asarray(jacobians, dtype=float)
    velocity = np.asarray(velocities, dtype=float)
    n, m = jac.shape[-2:]
    resolved = damped_resolve(
        read_only_view(jac.reshape(-1, n, m)), np.ascontiguousarray(velocity.reshape(-1, n)), float(damping) ** 2
    )
    out: np.ndarray = resolved.reshape(*velocity.shape[:-1], m)
    return out


class Kinematics:
    """Forward kinematics and position Jacobian of a serial arm, ``ẋ = J(θ) θ̇`` (eqs. 1–3).

    Args:
        robot: Name of a registered robot (:mod:`snac_gym.model.robots`; default ``"ur10"``). With
            ``urdf_path`` it only names the arm and supplies the default frames.
        ee_frame: URDF frame whose origin is the controlled point (default: the robot's,
            ``"tool0"`` for the UR arms).
        base_frame: URDF frame in which positions, velocities and Jacobians are expressed
            (default: the robot's, ``"base"`` for the UR arms).
        urdf_path: Optional path of another URDF with revolute joints only.
        model_error: A :class:`~snac_gym.model.model_error.ModelError` (or its ``--model-error`` text)
            written into the model: the kinematics a controller with a wrong arm model uses.
            ``None`` or a zero error: the true model. Its ``model`` part may only name this robot
            itself (another robot is refused: :meth:`with_model_error` builds that one).

    Attributes:
        n_joints: Number of actuated joints ``m``.
        task_dim: Dimension ``n`` of the task space (3: end-effector position).
        joint_names: Names of the actuated joints, in configuration order.
        velocity_limits: Joint speed limits from the URDF, rad/s, shape ``(m,)``.
        lower_limits, upper_limits: Joint position limits from the URDF, rad, shape ``(m,)``.

    The object keeps a Pinocchio ``Data`` workspace, so one instance must not be shared
    between threads; processes each build their own (instances pickle by their arguments).
    """

    task_dim: int = 3

    def __init__(
        self,
        robot: str = "ur10",
        ee_frame: str | None = None,
        base_frame: str | None = None,
        urdf_path: str | Path | None = None,
        model_error: Any = None,
    ) -> None:
        spec = get_robot(robot) if urdf_path is None or robot.lower() in robot_names() else None
        ee_frame = ee_frame if ee_frame is not None else (spec.ee_frame if spec else "tool0")
        base_frame = base_frame if base_frame is not None else (spec.base_frame if spec else "base")
        self.robot = robot
        self.ee_frame = ee_frame
        self.base_frame = base_frame
        self.urdf_path = Path(urdf_path) if urdf_path is not None else robot_urdf_path(robot)
        if not self.urdf_path.is_file():
            raise ValueError(f"URDF file not found: {self.urdf_path}")
        self.model = _locked(pin.buildModelFromUrdf(str(self.urdf_path)), spec.locked_joints if spec else ())
        if self.model.nq != self.model.nv:
            raise ValueError(
                f"{self.urdf_path.name}: only revolute/prismatic joints are supported (nq={self.model.nq}, "
                f"nv={self.model.nv})"
            )
        self.data = self.model.createData()
        self._ee_id = self._frame_id(ee_frame)
        base_id = self._frame_id(base_frame)
        if self.model.frames[base_id].parentJoint != 0:
            raise ValueError(f"base frame {base_frame!r} must be fixed to the world, not carried by a joint")
        pin.framesForwardKinematics(self.model, self.data, pin.neutral(self.model))
        world_from_base = self.data.oMf[base_id].copy()
        # Rows of this matrix rotate world-frame vectors into the base frame.
        self._base_from_world = np.ascontiguousarray(world_from_base.rotation.T)
        self._base_origin = world_from_base.translation.copy()
        # Re-root the model at the base frame (everything hanging from the universe is re-expressed
        # in it), so Pinocchio's world-aligned results are base-frame results with no per-call
        # rotation: the control step calls these 125-500 times a second.
        base_from_world = world_from_base.inverse()
        for joint in range(1, self.model.njoints):
            if self.model.parents[joint] == 0:
                self.model.jointPlacements[joint] = base_from_world * self.model.jointPlacements[joint]
        for frame in self.model.frames:
            if frame.parentJoint == 0:
                frame.placement = base_from_world * frame.placement
        error = _own_model_error(robot, self.urdf_path, model_error)
        if error is not None:
            error.check_joints(int(self.model.nq))  # a zero error of the wrong count too
        self.model_error = None if error is None or error.is_zero else error
        if self.model_error is not None:
            self.model_error.apply(self.model, self._ee_id)
        self.data = self.model.createData()

        self.n_joints: int = int(self.model.nq)
        self._q_shape = (self.n_joints,)
        self.joint_names: tuple[str, ...] = tuple(self.model.names[1:])
        self.velocity_limits = np.array(self.model.velocityLimit, dtype=float)
        self.lower_limits = np.array(self.model.lowerPositionLimit, dtype=float)
        self.upper_limits = np.array(self.model.upperPositionLimit, dtype=float)
        self._chain = BatchChain.from_model(self.model, self._ee_id)
        self._last_batch: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def with_model_error(self, model_error: Any) -> Kinematics:
        """The same arm (URDF, frames) with ``model_error`` written into its model: the one builder of the
        wrong model a controller is given under ``--model-error`` (:mod:`snac_gym.model.model_error`).

        With a ``model=NAME`` part the result is robot ``NAME``'s kinematics (its URDF) with the other parts
        written into it, expressed in this arm's end-effector and base frames where ``NAME`` has frames of those
        names, else in ``NAME``'s own; its ``robot`` is ``NAME`` and its ``model_error`` the other parts.

        Raises:
            ValueError: For a malformed error, one that names more joints than the arm has, or a ``model``
                with another joint count than this arm's (naming both robots and counts).
        """
        error = parse_model_error(model_error)
        if error is None or error.model is None or _is_robot(self.robot, self.urdf_path, error.model):
            return Kinematics(self.robot, self.ee_frame, self.base_frame, urdf_path=self.urdf_path, model_error=error)
        other = Kinematics(error.model)
        if other.n_joints != self.n_joints:
            raise ValueError(
                f"--model-error: model={error.model} has {other.n_joints} joints but {self.robot} has {self.n_joints}; "
                "the model must have the arm's joint count"
            )
        ee_frame = self.ee_frame if other.model.existFrame(self.ee_frame) else other.ee_frame
        base_frame = self.base_frame if other.model.existFrame(self.base_frame) else other.base_frame
        return Kinematics(error.model, ee_frame, base_frame, model_error=dataclasses.replace(error, model=None))

    def ee_mount(self) -> tuple[str, np.ndarray]:
        """The joint that carries the end-effector frame and the frame's offset in that joint's frame, m.

        The simulator merges the massless ``tool0`` into its parent link; this is how it finds the point again.
        """
        frame = self.model.frames[self._ee_id]
        return str(self.model.names[frame.parentJoint]), frame.placement.translation.copy()

    def position_lipschitz_bound(self) -> float:
        """L with ‖f(θ') − f(θ)‖ ≤ L‖θ' − θ‖ for every θ, θ' (no joint limits used): a certified bound on σ_max(J).

        Column j of J is z_j × (p − o_j) for a revolute joint, so ‖J_j‖ ≤ ‖p − o_j‖ ≤ d_j, the sum of
        the lengths of the fixed offsets from joint j to the end effector (the triangle inequality;
        rotations keep lengths). Then ‖Jδ‖ ≤ Σ d_j|δ_j| ≤ ‖d‖‖δ‖, and the mean-value theorem along the
        segment gives the Lipschitz bound L = ‖d‖ (a prismatic joint's column has norm 1: d_j = 1).
        """
        frame = self.model.frames[self._ee_id]
        reach = float(np.linalg.norm(frame.placement.translation))
        lengths = np.zeros(self.n_joints)
        joint = int(frame.parentJoint)
        while joint > 0:  # from the end effector's joint back to the base, accumulating the offsets
            index = self.model.joints[joint].idx_q
            kind = self.model.joints[joint].shortname()
            lengths[index] = 1.0 if "P" in kind.removeprefix("JointModel")[:2] else reach
            reach += float(np.linalg.norm(self.model.jointPlacements[joint].translation))
            joint = int(self.model.parents[joint])
        return float(np.linalg.norm(lengths))

    def _frame_id(self, name: str) -> int:
        if not self.model.existFrame(name):
            names = [f.name for f in self.model.frames]
            raise ValueError(f"frame {name!r} not in {self.urdf_path.name}; frames: {names}")
        return int(self.model.getFrameId(name))

    # -- pickling: rebuild from the arguments, the Pinocchio objects are not picklable
    def __reduce__(self) -> tuple[Any, ...]:
        urdf = None if self.urdf_path == robot_urdf_path(self.robot) else self.urdf_path
        return (Kinematics, (self.robot, self.ee_frame, self.base_frame, urdf, self.model_error))

    def __repr__(self) -> str:
        return (
            f"Kinematics(robot={self.robot!r}, ee_frame={self.ee_frame!r}, base_frame={self.base_frame!r}, "
            f"n_joints={self.n_joints}"
            + (f", model_error={self.model_error.spec()!r})" if self.model_error is not None else ")")
        )

    def _check_q(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != self._q_shape:
            raise ValueError(f"joint vector must have shape ({self.n_joints},), got {q.shape}")
        return q

    def forward(self, q: np.ndarray) -> np.ndarray:
        """End-effector position ``x = f(θ)`` in the base frame, metres (eq. 1)."""
        q = self._check_q(q)
        pin.forwardKinematics(self.model, self.data, q)
        x: np.ndarray = pin.updateFramePlacement(self.model, self.data, self._ee_id).translation.copy()
        return x

    def base_to_world(self, x: np.ndarray) -> np.ndarray:
        """Map a base-frame position to the URDF world frame (the simulator's frame)."""
        x_world: np.ndarray = self._base_from_world.T @ np.asarray(x, dtype=float) + self._base_origin
        return x_world

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """Position Jacobian ``J = ∂f/∂θ`` in the base frame, shape ``(task_dim, n_joints)`` (eq. 2)."""
        q = self._check_q(q)
        jac: np.ndarray = pin.computeFrameJacobian(self.model, self.data, q, self._ee_id, pin.LOCAL_WORLD_ALIGNED)[:3]
        return jac

    def forward_and_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(f(θ), J(θ))`` from one kinematics pass; the form controllers call each step."""
        q = self._check_q(q)
        jac = pin.computeFrameJacobian(self.model, self.data, q, self._ee_id, pin.LOCAL_WORLD_ALIGNED)[:3]
        return self.data.oMf[self._ee_id].translation.copy(), jac

    def _check_batch(self, qs: np.ndarray) -> np.ndarray:
        qs = np.asarray(qs, dtype=float)
        if qs.ndim != 2 or qs.shape[1] != self.n_joints:
            raise ValueError(f"configurations must have shape (B, {self.n_joints}), got {qs.shape}")
        return qs

    def forward_batch(self, qs: np.ndarray) -> np.ndarray:
        """Positions for a batch of configurations, shape ``(B, n_joints) -> (B, task_dim)``.

        Same evaluation and caching as :meth:`forward_and_jacobian_batch`.
        """
        return self.forward_and_jacobian_batch(qs)[0]

    def jacobian_batch(self, qs: np.ndarray) -> np.ndarray:
        """``J(θᵢ)`` for a batch, shape ``(B, n_joints) -> (B, task_dim, n_joints)`` (the batch policies' form)."""
        return self.forward_and_jacobian_batch(qs)[1]

    def forward_and_jacobian_batch(self, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(f(θᵢ), J(θᵢ))`` for a batch, shapes ``(B, task_dim)`` and ``(B, task_dim, n_joints)``.

        The evaluator, the batch policies and the optimal-control solver call this over many
        samples or whole trajectories. Batches are evaluated by :class:`BatchChain` (a compiled
        loop over the batch, several times faster than Pinocchio called per configuration:
        ``python docs/scripts/kernel_speed.py``) when the model allows it, by a loop over
        Pinocchio otherwise; either way a row does not depend on the rest of the batch. The last batch
        is remembered, because in each control step of the evaluator the engine asks for
        ``f(θ)`` of all samples and the policies then for ``J(θ)`` of the same configurations;
        the arrays returned are therefore read-only.
        """
        qs = self._check_batch(qs)
        last = self._last_batch
        # The same bytes, not np.array_equal: 0.5-3 µs against 5-7 µs on the evaluator's batches (it is asked twice
        # a control step), and only bit-identical input gets the remembered output (0.0 and -0.0 differ; a NaN row
        # equals itself).
        if last is not None and last[0].shape == qs.shape and last[0].tobytes() == qs.tobytes():
            return last[1], last[2]
        if self._chain is not None:
            positions, jacobians = self._chain.forward_and_jacobian(qs)
        else:
            n = self.task_dim
            positions = np.empty((len(qs), n))
            jacobians = np.empty((len(qs), n, self.n_joints))
            model, data, frame, placements = self.model, self.data, self._ee_id, self.data.oMf
            for k, q in enumerate(qs):
                jacobians[k] = pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL_WORLD_ALIGNED)[:n]
                positions[k] = placements[frame].translation
        positions.setflags(write=False)
        jacobians.setflags(write=False)
        self._last_batch = (qs.copy(), positions, jacobians)
        return positions, jacobians

    def error_curvature_batch(self, qs: np.ndarray, errors: np.ndarray) -> np.ndarray | None:
        """``Σᵢ eᵢ ∂²fᵢ/∂θ²`` for configurations ``(B, m)`` and their position errors ``(B, 3)``: ``(B, m, m)``.

        With ``JᵀJ`` it is the Hessian of ½‖f(θ) − x_d‖² (the exact Newton matrix of the trajectory optimiser's
        error term, :func:`snac_gym.control.gauss_newton.gauss_newton`). ``None`` for a model that
        :class:`BatchChain` cannot evaluate (then only the Gauss-Newton part is available).
        """
        if self._chain is None:
            return None
        return self._chain.error_curvature(self._check_batch(qs), errors)

    def frame_batch(self, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The end-effector frame and its full Jacobian for a batch, through Pinocchio per configuration.

        Returns:
            Positions ``(B, 3)``, rotations ``(B, 3, 3)`` (frame axes in the base frame), and the
            linear and angular Jacobians ``(B, 3, m)`` (``LOCAL_WORLD_ALIGNED``: ṗ = J_v θ̇, ω = J_ω θ̇).
        """
        qs = self._check_batch(qs)
        count = len(qs)
        positions, rotations = np.empty((count, 3)), np.empty((count, 3, 3))
        linear, angular = np.empty((count, 3, self.n_joints)), np.empty((count, 3, self.n_joints))
        model, data, frame = self.model, self.data, self._ee_id
        for k, q in enumerate(qs):
            jacobian = pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL_WORLD_ALIGNED)
            linear[k], angular[k] = jacobian[:3], jacobian[3:]
            placement = data.oMf[frame]
            positions[k], rotations[k] = placement.translation, placement.rotation
        return positions, rotations, linear, angular

    def singular_values(self, q: np.ndarray) -> np.ndarray:
        """Singular values of ``J(θ)``, largest first."""
        return np.linalg.svd(self.jacobian(q), compute_uv=False)

    def inverse_position(
        self,
        target: np.ndarray,
        q_init: np.ndarray,
        tol: float = 1e-6,
        max_iters: int = 200,
        damping: float = 1e-2,
    ) -> tuple[np.ndarray, bool]:
        """Damped-least-squares position IK, used to check that points are reachable.

        Args:
            target: Desired end-effector position in the base frame, metres.
            q_init: Starting configuration.
            tol: Position tolerance, metres.
            max_iters: Iteration cap.
            damping: Levenberg-Marquardt damping λ in ``Jᵀ(JJᵀ + λ²I)⁻¹``.

        Returns:
            ``(q, converged)``: the last iterate (inside the joint limits) and whether
            ``‖f(q) − target‖ ≤ tol``.
        """
        target = np.asarray(target, dtype=float)
        lower, upper = self.lower_limits, self.upper_limits
        q = np.clip(self._check_q(q_init).copy(), lower, upper)
        damping_matrix = damping**2 * np.eye(self.task_dim)
        # Called tens of thousands of times per sample set (every point of every candidate ellipse):
        # Pinocchio and the small array operations are called directly, and max-then-min is np.clip's
        # arithmetic without its dispatch, so the iterates are the same bit for bit.
        model, data, frame, placements = self.model, self.data, self._ee_id, self.data.oMf
        n = self.task_dim
        for _ in range(max_iters):
            jac = pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL_WORLD_ALIGNED)[:n]
            err = target - placements[frame].translation
            if err @ err <= tol * tol:
                return q, True
            step = jac.T @ np.linalg.solve(jac @ jac.T + damping_matrix, err)
            norm = math.sqrt(step @ step)  # np.linalg.norm's own sum and root
            if norm > 0.5:  # a trust region keeps the iteration from jumping across branches
                step *= 0.5 / norm
            q = np.minimum(np.maximum(q + step, lower), upper)
        err = target - self.forward(q)
        return q, bool(err @ err <= tol * tol)


def _is_robot(robot: str, urdf_path: Path, name: str) -> bool:
    """Whether ``robot`` with ``urdf_path`` is the registered robot ``name`` (its URDF)."""
    return name == robot.lower() and urdf_path == robot_urdf_path(name)


def _own_model_error(robot: str, urdf_path: Path, model_error: Any) -> ModelError | None:
    """``model_error`` parsed, for ``robot`` itself: a ``model`` part naming this robot dropped (nothing to change).

    Raises:
        ValueError: If its ``model`` names another robot (:meth:`Kinematics.with_model_error` builds that one).
    """
    error = parse_model_error(model_error)
    if error is None or error.model is None:
        return error
    if not _is_robot(robot, urdf_path, error.model):
        raise ValueError(
            f"--model-error model={error.model}: Kinematics({robot!r}) does not become another robot; "
            f"Kinematics({robot!r}).with_model_error(...) builds {error.model}'s kinematics with the other parts"
        )
    return dataclasses.replace(error, model=None)


def _locked(model: pin.Model, joints: tuple[str, ...]) -> pin.Model:
    """``model`` with ``joints`` held at their neutral value clipped to their limits (e.g. a gripper's fingers)."""
    if not joints:
        return model
    missing = [name for name in joints if not model.existJointName(name)]
    if missing:
        raise ValueError(f"locked joints {missing} are not in the URDF; joints: {list(model.names[1:])}")
    reference = np.clip(pin.neutral(model), model.lowerPositionLimit, model.upperPositionLimit)
    return pin.buildReducedModel(model, [model.getJointId(name) for name in joints], reference)


@lru_cache(maxsize=8)
def shared_kinematics(robot: str) -> Kinematics:
    """One :class:`Kinematics` per registered robot and process, for code that only reads it.

    The instance keeps a Pinocchio workspace: do not share it between threads (build your own).
    """
    return Kinematics(robot)
