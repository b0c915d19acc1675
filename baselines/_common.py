"""What the baseline controllers (rnn, svf, dls, lqr, mpc) share: reading the observation, the task-space
feedback term, staying inside the joint-velocity limits, the resolved-rate skeleton and the checks of their
parameters.

Every baseline commands the joint velocities ``u`` of ``ẋ = J u`` (eq. 3 of the paper) from
the *reference velocity*

    v = ẋ_d + K (x_d − x) = ẋ_d − K e,        e = x − x_d (the observation's error field),

i.e. the task-space velocity that makes ``ė = −K e`` when ``J u = v`` holds exactly. For
regulation ``ẋ_d = 0`` (the reach env's observation carries zeros there), so one formula
serves both tasks. The controllers differ in how they map ``v`` to ``u``.

The Jacobian comes from the env's shared :class:`~snac_gym.model.kinematics.Kinematics`; the
baselines have no kinematics of their own.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from snac_gym.model.joint_limits import make_limit_box
from snac_gym.policies.base import BasePolicy, positive_float, scale_rows_into_limits


def clip_to_box(command: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """Projection ``P_Ω`` onto the box ``Ω = {u : −limits ≤ u ≤ limits}``, component-wise.

    ``minimum(maximum(·))`` instead of ``np.clip``: the same result at half the overhead
    on 6-vectors, and this runs at every control step.
    """
    return np.minimum(np.maximum(command, -limits), limits)


def scale_into_box(command: np.ndarray, limits: np.ndarray) -> tuple[np.ndarray, float]:
    """Scale ``command`` uniformly so that ``|uᵢ| ≤ limitsᵢ`` for every joint.

    Unlike component-wise clipping, uniform scaling keeps the direction of ``u`` and hence
    of the end-effector velocity ``J u``: a saturated resolved-rate step still moves the end
    effector straight towards the reference, only slower.

    Returns:
        ``(u, scale)``: the command inside the box (``command`` itself when it was inside)
        and the factor ``scale ≥ 1`` it was divided by (1 when inside).
    """
    scale = float(np.max(np.abs(command) / limits))
    if scale > 1.0:
        command /= scale
        # u/scale can land one rounding step outside the bound it was scaled onto.
        return clip_to_box(command, limits), scale
    return command, 1.0


def transpose(matrices: np.ndarray) -> np.ndarray:
    """``Aᵀ`` of one matrix (or vector), or of each matrix of a stack (the last two axes swapped).

    The shared math of ``act`` and ``act_batch`` is written once for one sample and for B
    samples with vectors as columns: J ``(n, m)``, v ``(n,)`` or J ``(B, n, m)``, v ``(B, n, 1)``,
    so that plain ``@`` and ``np.linalg.solve`` serve both and ``act`` keeps its numbers and speed.
    """
    return matrices.T if matrices.ndim <= 2 else np.swapaxes(matrices, -1, -2)  # .T: 4× cheaper on one


class ObservationReader:
    """Precomputed slices of the fields the baselines read (q, e, ẋ_d), so ``act`` indexes
    the flat observation directly instead of building named views at every step."""

    def __init__(self, policy: BasePolicy) -> None:
        slices = policy.layout.slices
        self.size = policy.layout.size
        self.q = slices["q"]
        # e and ẋ_d index the last axis: one observation or a (B, size) batch alike.
        self.e = (Ellipsis, slices["e"])
        self.xdot_d = (Ellipsis, slices["xdot_d"])

    def read(self, obs: np.ndarray) -> np.ndarray:
        """``obs`` as a float array of the layout's size.

        Raises:
            ValueError: If ``obs`` does not have the layout's shape.
        """
        obs = np.asarray(obs, dtype=float)
        if obs.shape != (self.size,):
            raise ValueError(f"observation must have shape ({self.size},), got {obs.shape}")
        return obs

    def read_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """``obs_batch`` as a float ``(B, size)`` array.

        Raises:
            ValueError: If it does not have that shape.
        """
        obs_batch = np.asarray(obs_batch, dtype=float)
        if obs_batch.ndim != 2 or obs_batch.shape[1] != self.size:
            raise ValueError(f"observations must have shape (B, {self.size}), got {obs_batch.shape}")
        return obs_batch


def reference_velocity(obs: np.ndarray, reader: ObservationReader, gain: float, feedforward: bool = True) -> np.ndarray:
    """``v = ẋ_d + K (x_d − x) = ẋ_d − K e`` from an observation (``ẋ_d`` dropped without ``feedforward``).

    ``obs`` is one observation or a ``(B, size)`` batch (then one row of ``v`` per row).
    """
    feedback = obs[reader.e] * -gain
    if feedforward:
        feedback += obs[reader.xdot_d]
    return feedback


class ResolvedRatePolicy(BasePolicy):
    """Closed-loop inverse kinematics ``u = sat(G(J) (ẋ_d + K (x_d − x)))``.

    Subclasses give the generalised inverse ``G(J)`` through :meth:`resolve`; this class reads
    the observation, builds the reference velocity, calls the shared kinematics for ``J`` and
    scales the result into the velocity limits (:func:`scale_into_box`).

    The evaluator's optional batch protocol (``reset_batch`` / ``act_batch``, see
    ``snac_gym/policies/base.py``) runs B episodes at once: the controllers are memoryless, so row i
    of ``act_batch`` is ``act`` of row i; subclasses vectorise :meth:`resolve_batch` (the default
    calls :meth:`resolve` per row).

    Args:
        env: The env (or :class:`~snac_gym.policies.base.PolicyContext`) to drive.
        gain: Task-space feedback gain ``K`` (1/s); the effort knob: the command at the start
            of a regulation episode is about ``K‖e₀‖`` in task space.
        joint_limits: Clamp the command into the position-limit box Ω(θ)
            (:mod:`snac_gym.model.joint_limits`; these controllers have no mechanism of their own);
            ``None`` (default): on for the 7-DOF arms only.

    Attributes:
        effort_parameter: Name of the constructor argument that scales the control effort
            (``"gain"``), for the evaluator's effort matching.
    """

    effort_parameter = "gain"

    def __init__(self, env: Any, gain: float, joint_limits: bool | None = None) -> None:
        super().__init__(env)
        self.gain = positive_float("gain", gain)
        self._reader = ObservationReader(self)
        self.limit_box = make_limit_box(self, joint_limits)

    def resolve(self, jacobian: np.ndarray, task_velocity: np.ndarray) -> np.ndarray:
        """Joint velocities ``G(J) v`` before saturation (a new array)."""
        raise NotImplementedError

    #: Whether :meth:`resolve` also takes stacks with vectors as columns (see :func:`transpose`).
    resolves_stacks = False

    def resolve_batch(self, jacobians: np.ndarray, task_velocities: np.ndarray) -> np.ndarray:
        """:meth:`resolve` of each row: ``(B, n, m)``, ``(B, n)`` -> ``(B, m)``."""
        if self.resolves_stacks:
            return self.resolve(jacobians, task_velocities[..., None])[..., 0]
        return np.array([self.resolve(j, v) for j, v in zip(jacobians, task_velocities, strict=True)])

    def reset_batch(self, seeds: Sequence[int]) -> None:
        """Start ``len(seeds)`` episodes (nothing to set: the controller has no state)."""
        self.internals = {}

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)`` for observations ``(B, size)``: row i is :meth:`act` of row i."""
        obs_batch = self._reader.read_batch(obs_batch)
        task_velocities = reference_velocity(obs_batch, self._reader, self.gain)
        jacobians = self.kinematics.jacobian_batch(obs_batch[:, self._reader.q])
        commands = scale_rows_into_limits(self.resolve_batch(jacobians, task_velocities), self.velocity_limits)
        return commands if self.limit_box is None else self.limit_box.clamp(obs_batch[:, self._reader.q], commands)

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command (rad/s) for ``obs``, inside the velocity limits."""
        obs = self._reader.read(obs)
        task_velocity = reference_velocity(obs, self._reader, self.gain)
        jacobian = self.kinematics.jacobian(obs[self._reader.q])
        command, scale = scale_into_box(self.resolve(jacobian, task_velocity), self.velocity_limits)
        self.internals = {"saturation_scale": scale}
        return command if self.limit_box is None else self.limit_box.clamp(obs[self._reader.q], command)


def positive_int(name: str, value: Any) -> int:
    """``value`` as an int ≥ 1 (a whole float like 2.0 is accepted).

    Raises:
        ValueError: If it is not one.
    """
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a positive integer, got {value!r}") from exc
    if not (np.isfinite(number) and number >= 1 and number == int(number)):
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(number)


def one_of(name: str, value: Any, choices: Sequence[str]) -> str:
    """``value`` if it is one of ``choices``.

    Raises:
        ValueError: If it is not, naming ``name`` and the choices.
    """
    if value not in choices:
        raise ValueError(f"{name} must be one of {tuple(choices)}, got {value!r}")
    return str(value)
