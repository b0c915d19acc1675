"""Recurrent (dual) neural network kinematic control with position feedback.

Reference:
    S. Li, Y. Zhang and L. Jin, "Kinematic control of redundant manipulators using neural
    networks", IEEE Trans. Neural Netw. Learn. Syst. 28(10):2243–2254, 2017.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from snac_gym.baselines._common import (
    ObservationReader,
    positive_float,
    reference_velocity,
    transpose,
)

from snac_gym.model.joint_limits import make_limit_box
from snac_gym.policies.base import BasePolicy

#: Integration schemes of the network dynamics (see :class:`RNNPolicy`).
INTEGRATORS = ("semi-implicit", "euler")
#: Explicit Euler sub-steps are chosen so that (Δt/n)‖J‖²_F/ε ≤ this; stability needs < 2.
EULER_STEP_BOUND = 1.0


class RNNPolicy(BasePolicy):
    """Dual recurrent neural network solving the kinematic QP online (Li, Zhang and Jin, 2017).

    **Problem.** At every instant the network solves

        minimise ½ uᵀu   subject to   J(θ) u = ẋ_d + k (x_d − x),   u ∈ Ω = {|uᵢ| ≤ u̅ᵢ}

    (least joint-velocity norm; the equality is the task-space velocity with position
    feedback; Ω is the box of joint-velocity limits u̅).

    **Network.** Its dual neural network has one neuron per task coordinate, state λ ∈ ℝⁿ:

        ε λ̇ = ẋ_d + k (x_d − x) − J P_Ω(Jᵀλ)          (dynamic part: neural dynamics)
        u   = P_Ω(Jᵀλ)                                  (static part: output layer)

    with ``P_Ω`` the projection onto Ω (component-wise clipping) and ε > 0 the network's time
    scale. At an equilibrium ``J u = ẋ_d + k(x_d − x)`` holds with u the QP's solution (the
    KKT conditions of the QP), so with the robot's ``ẋ = J u`` the error obeys ``ė = −k e``
    while no bound is active. ``velocity_compensation=True`` (default) gives the paper's
    tracking form with the feed-forward ẋ_d; for regulation ẋ_d = 0 and it is the
    position-regulation form ``ε λ̇ = k (x_d − x) − J P_Ω(Jᵀλ)``. ``velocity_compensation=False``
    drops ẋ_d while tracking (the uncompensated form, which lags a moving target by
    about ``‖ẋ_d‖/k``).

    **Assumptions** (the paper's text was not available to check equation by equation):

    * The equations above follow the project's specification of the baseline, the dual neural network of
      Zhang, Wang and Xia (IEEE TNN 14(3), 2003) that the paper modifies, and the paper's
      published summary (position feedback in the network input so that position error does
      not accumulate; a velocity-compensated variant for tracking; a static output
      ``u = P_Ω(Jᵀλ)`` and dynamic λ). The paper also admits non-convex Ω; ours is a box,
      the convex case.
    * **Joint position limits** enter Ω as in Li et al., through θ-dependent speed bounds
      ``Ω(θ) = {max(−ū, κ(θ⁻ + δ − θ)) ≤ u ≤ min(ū, κ(θ⁺ − δ − θ))}``
      (:mod:`snac_gym.model.joint_limits`), the network's own mechanism: at its equilibrium the
      other joints make the task motion a bounded joint cannot. On by default on the 7-DOF
      arms (``joint_limits=None``); on the UR arms Ω is the velocity box ``|uᵢ| ≤ ūᵢ``.
    * The feedback gain k is a scalar (the same for every task axis), λ(0) = 0 at every
      ``reset`` (so u(0) = 0: the arm starts at rest), and ``x``, ``x_d``, ``ẋ_d`` are read from
      the observation, J from the shared kinematics at the measured θ.

    **Discretisation** (ours; the paper works in continuous time). The network state
    persists across control steps and is integrated over one control period Δt per ``act``,
    with θ (hence J) and the feedback term frozen over the period; the output uses the
    updated λ. Linearising the right-hand side where the active set is fixed
    (``D = diag(1 for joints strictly inside their bound)``, ``∂P_Ω(Jᵀλ)/∂λ = D Jᵀ``):

    * ``"euler"``: ``λ ← λ + (Δt/ε)(r − J P_Ω(Jᵀλ))``, r = ẋ_d + k(x_d − x), is stable only
      if ``(Δt/ε)·‖J D Jᵀ‖ < 2`` (the eigenvalues of ``I − (Δt/ε) J D Jᵀ`` must lie in (−1, 1]).
      For the UR10, ‖JJᵀ‖ = σ_max² reaches ≈ 2.3 m²/rad², so at Δt = 8 ms a single step
      needs ε > 9 ms. The update therefore takes ``n = ⌈Δt‖J‖²_F/ε⌉`` sub-steps of Δt/n
      (‖J‖²_F ≥ ‖JJᵀ‖ is cheap), keeping ``(Δt/n)‖JJᵀ‖/ε ≤ 1`` (:data:`EULER_STEP_BOUND`).
    * ``"semi-implicit"`` (default): one linearly-implicit (Rosenbrock–Euler) step,
      ``(ε/Δt · I + J D Jᵀ) Δλ = r − J P_Ω(Jᵀλ)``, ``λ ← λ + Δλ``: the stiff linear part is
      treated implicitly, so the network update is unconditionally stable for any ε > 0
      (its iteration matrix ``(I + (Δt/ε) J D Jᵀ)⁻¹`` has eigenvalues in (0, 1]) and costs one
      n×n solve. Its fixed points are exactly the network's equilibria. Coupled with the
      robot (``x ← x + Δt J u``), each task direction with ``g`` an eigenvalue of JJᵀ has the
      iteration matrix ``[[1, a k], [−Δt g, 1 + a g − Δt g a k]] / (1 + a g)`` on (λ, x_d − x),
      a = Δt/ε, whose determinant is ``1/(1 + a g)`` and which is stable (Jury) whenever
      ``k Δt < 2``, whatever ε.

    Small ε makes the network fast compared with the arm (the QP is tracked closely); as
    ε → 0 the semi-implicit step gives ``u = J⁺ r`` when no bound is active.

    Args:
        env: The env (or policy context) to drive.
        gain: Position feedback gain k, 1/s; the effort knob (``effort_parameter``): the
            network makes the end effector approach the target at ``k‖e‖``.
        epsilon: Network time scale ε, s (default 1 ms, fast against the arm's motion and
            the 8 ms control period; see docs/baselines.md for the choice).
        integrator: ``"semi-implicit"`` (default) or ``"euler"`` (explicit, sub-stepped).
        velocity_compensation: Add the feed-forward ẋ_d to the network input (default
            ``True``; no effect in regulation, where ẋ_d = 0).
        joint_limits: Add the position limits to Ω (``None``: on for the 7-DOF arms only).

    **Batch protocol** (``snac_gym/policies/base.py``): ``reset_batch(seeds)`` starts B networks at
    rest and ``act_batch`` advances them together, the dual state a ``(B, n)`` array; the update
    is the same code as ``act``'s, row by row.

    Attributes:
        effort_parameter: ``"gain"``.
        internals: After each ``act``: ``dual_state`` (λ) and ``active_bounds`` (joints at
            their velocity limit).

    Raises:
        ValueError: On a non-positive ``gain`` or ``epsilon``, ``gain·dt ≥ 2`` or an unknown
            integrator.
    """

    effort_parameter = "gain"

    def __init__(
        self,
        env: Any,
        gain: float = 2.0,
        epsilon: float = 1e-3,
        integrator: str = "semi-implicit",
        velocity_compensation: bool = True,
        joint_limits: bool | None = None,
    ) -> None:
        super().__init__(env)
        self.limit_box = make_limit_box(self, joint_limits)
        self.gain = positive_float("gain", gain)
        self.epsilon = positive_float("epsilon", epsilon)
        if self.gain * self.dt >= 2.0:
            raise ValueError(f"gain * dt must be below 2 for a stable discrete loop, got {self.gain} * {self.dt}")
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
        self.integrator = integrator
        self.velocity_compensation = bool(velocity_compensation)
        self._reader = ObservationReader(self)
        self._implicit_diagonal = (self.epsilon / self.dt) * np.eye(self.kinematics.task_dim)
        self._dual = np.zeros(self.kinematics.task_dim)
        self._batch_dual: np.ndarray | None = None  # λ of the batch protocol's B networks, (B, n, 1)
        self._velocity_box = (-self.velocity_limits, self.velocity_limits)
        self._column_box = (-self.velocity_limits[:, None], self.velocity_limits[:, None])

    @property
    def dual_state(self) -> np.ndarray:
        """The network state λ (a copy)."""
        return self._dual.copy()

    def reset(self, seed: int | None = None) -> None:
        """Put the network at rest (λ = 0); ``seed`` is unused (the policy is deterministic)."""
        self._dual = np.zeros(self.kinematics.task_dim)
        self.internals = {}

    def reset_batch(self, seeds: Sequence[int]) -> None:
        """Start ``len(seeds)`` episodes, each network at rest (λ = 0); the seeds are unused."""
        self._batch_dual = np.zeros((len(seeds), self.kinematics.task_dim, 1))  # λ of each network, a column
        self.internals = {}

    def network_update(self, jacobian: np.ndarray, network_input: np.ndarray) -> np.ndarray:
        """Advance λ over one control period with J and r = ẋ_d + k(x_d − x) frozen.

        Returns:
            The output ``u = P_Ω(Jᵀλ)`` at the updated λ.
        """
        return self._advance(self._dual, jacobian, network_input, self._velocity_box)

    def _advance(
        self, dual: np.ndarray, jacobian: np.ndarray, network_input: np.ndarray, box: tuple[np.ndarray, np.ndarray]
    ) -> np.ndarray:
        """:meth:`network_update` on ``dual`` (updated in place) for one network: λ, r ``(n,)``,
        J ``(n, m)``, the bounds of Ω ``(m,)``; or for B at once, vectors as columns: λ, r
        ``(B, n, 1)``, J ``(B, n, m)``, bounds ``(m, 1)`` or ``(B, m, 1)`` (see
        :func:`snac_gym.baselines._common.transpose`)."""
        lower, upper = box
        jacobian_t = transpose(jacobian)
        if self.integrator == "semi-implicit":
            joint_drive = jacobian_t @ dual
            free = (joint_drive > lower) & (joint_drive < upper)  # D: joints whose output is not clipped
            residual = network_input - jacobian @ _project(joint_drive, box)
            system = (jacobian * transpose(free)) @ jacobian_t + self._implicit_diagonal
            dual += np.linalg.solve(system, residual)
        else:
            frobenius_sq = np.einsum("...ij,...ij->...", jacobian, jacobian)
            substeps = np.maximum(1.0, np.ceil(self.dt * frobenius_sq / (self.epsilon * EULER_STEP_BOUND)))
            rate = self.dt / (substeps * self.epsilon)
            if dual.ndim > 1:
                substeps, rate = substeps[:, None, None], rate[:, None, None]
            for step in range(int(np.max(substeps))):
                increment = rate * (network_input - jacobian @ _project(jacobian_t @ dual, box))
                dual += np.where(substeps > step, increment, 0.0)  # each network its own count of sub-steps
        return _project(jacobian_t @ dual, box)

    def _box(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The bounds of Ω for θ ``(m,)``: the velocity box, or Ω(θ) with the position limits."""
        return self._velocity_box if self.limit_box is None else self.limit_box.bounds(q)

    def _column_bounds(self, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The bounds of Ω for θ ``(B, m)`` as columns: ``(m, 1)`` or ``(B, m, 1)``."""
        if self.limit_box is None:
            return self._column_box
        lower, upper = self.limit_box.bounds(qs)
        return lower[..., None], upper[..., None]

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command (rad/s) for ``obs``; advances the network by one period."""
        obs = self._reader.read(obs)
        network_input = reference_velocity(obs, self._reader, self.gain, feedforward=self.velocity_compensation)
        q = obs[self._reader.q]
        jacobian = self.kinematics.jacobian(q)
        lower, upper = box = self._box(q)
        command = self._advance(self._dual, jacobian, network_input, box)
        self.internals = {"dual_state": self._dual.copy(), "active_bounds": (command <= lower) | (command >= upper)}
        return command

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)`` for observations ``(B, size)``; advances the B networks by one period.

        Raises:
            RuntimeError: If called before :meth:`reset_batch`.
        """
        if self._batch_dual is None:
            raise RuntimeError("call reset_batch() before act_batch()")
        obs_batch = self._reader.read_batch(obs_batch)
        network_input = reference_velocity(obs_batch, self._reader, self.gain, feedforward=self.velocity_compensation)
        qs = obs_batch[:, self._reader.q]
        jacobians = self.kinematics.jacobian_batch(qs)
        commands = self._advance(self._batch_dual, jacobians, network_input[..., None], self._column_bounds(qs))
        return commands[..., 0]


def _project(command: np.ndarray, box: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``P_Ω``: ``command`` clipped component-wise into ``box = (lower, upper)`` (``minimum(maximum(·))``,
    as :func:`snac_gym.baselines._common.clip_to_box`, which it equals for the velocity box)."""
    return np.minimum(np.maximum(command, box[0]), box[1])
