"""SNAC with a critic that converges: the paper's structure, tuned by the HJB residual.

The paper's weight law (eq. 19 / 38) descends the Lyapunov function J_s = ½‖s‖², not the HJB
equation: it contains no Q and its critic does not approach the optimal value function
(docs/snac.md). This controller keeps the paper's structure, one critic ``V̂ = Ŵᵀσ(e)`` over the
quadratic basis, the command from ``∇V̂`` (eq. 15), eq. 19 as a stabilising term, and tunes Ŵ
by the HJB residual instead.

**Critic and command.** ``V̂(e) = Ŵᵀσ(e) = eᵀP̂e`` (:func:`~snac_gym.control.optimality.quadratic_weights_to_matrix`)::

    u_fb = −½ R⁻¹ Jᵀ ∇V̂(e) = −R⁻¹ Jᵀ P̂ e                  (eq. 15)
    u    = sat(J⁺_R ẋ_d + u_fb)

For regulation ẋ_d = 0. For tracking the feed-forward ``J⁺_R ẋ_d = R⁻¹Jᵀ(JR⁻¹Jᵀ)⁻¹ẋ_d`` turns
``ė = J u − ẋ_d`` into ``ė = J u_fb``, the regulation problem, whose cost
``∫ eᵀQe + u_fbᵀRu_fb`` is finite. The paper's augmented, undiscounted tracking cost is
infinite for any controller that follows the ellipse (u ≠ 0 forever; docs/baselines.md, LQR),
so a critic cannot converge to it; the discounted alternative (Modares & Lewis 2014) would
leave a steady error that grows with the discount. The feed-forward form keeps a zero steady
error and a well-posed critic; its price is that ``u`` is not the minimiser of the full
instantaneous cost (the paper's remark on Kiumarsi et al. 2015).

**Saturation** ``sat``: a command beyond the joint-velocity limits is scaled as a whole into them,
the rule of the frozen-Jacobian LQR (:class:`snac_gym.baselines.lqr.LQRPolicy`, whose optimum this critic
learns), so that the two differ only in the critic. Scaling keeps the direction of ``u`` and of
``ė = J u``: a feedback that decreases ``½‖e‖²`` (``eᵀJu < 0``) still does when saturated, only
slower, while clipping each joint turns ``J u`` away from the error and can undo that decrease.

**HJB residual** at an error ``d`` with the critic's own command ``û(d) = −R⁻¹JᵀP̂d`` (eq. 9)::

    δ(d) = ∇V̂(d)ᵀ J û(d) + dᵀQd + û(d)ᵀRû(d) = ω(d)ᵀŴ + dᵀQd + û(d)ᵀRû(d),
    ω(d) = ∇σ(d) J û(d)

δ = 0 at every d exactly when P̂ solves the frozen-Jacobian ARE (P̂ = P*(J)). Since û minimises
the Hamiltonian, ∂δ/∂Ŵ = ω (envelope theorem).

**Weight law** (Vamvoudakis & Lewis 2010; Dierks & Jagannathan 2010) on the residuals at a set
of errors D: the current error direction e/‖e‖ plus the n(n+1)/2 fixed unit directions
``{eᵢ} ∪ {(eᵢ + eⱼ)/√2}``, at which the known model ė = J u lets the residual be evaluated
without moving there (Bellman-error extrapolation, Kamalapurkar, Walters & Dixon, Automatica
2016). This gives the persistent excitation that a straight reach cannot: along one path only
the residual in one direction is observed. The normalised gradient is preconditioned by its
Gram matrix, the least-squares gain of the same references::

    Ŵ̇ = −α Γ Σ_{d∈D} ω(d) δ(d) / ρ(d),   Γ = (Σ ω ωᵀ/ρ + εI)⁻¹,   ρ = 1 + ωᵀω
         + α_s 1[eᵀJu_fb > 0] ∇σ(e) J R⁻¹ Jᵀ e          (eq. 19, only while V̇ of J_s is not negative)

integrated by one Euler step per control period. With Γ the step is a damped Newton step on the
ARE (Kleinman's iteration), so the critic follows P*(J) as θ moves.

**Projection.** The HJB residual vanishes at every solution of ``P̂GP̂ = Q``, ``−P*`` included,
whose command drives the error away; Kleinman's iteration converges to the stabilising P*
from any stabilising start and keeps every iterate positive definite. So after each step Ŵ
is projected (the standard projection of adaptive control) onto the convex set
``{P̂ ⪰ λ_floor I}``: eigenvalues of P̂ below ``min_eigenvalue`` are raised to it. Without it
the paper's random Ŵ₀, indefinite on most seeds, converged to a non-stabilising solution in
the reach demo (docs/snac.md).

**Initial weights and warm start.** Ŵ₀ ~ U(0, 1) from the reset seed, as the paper's
"initialized randomly", then projected. Before the first command the same law runs
``warm_start_iterations`` full steps (α·Δt = 1, Kleinman's iteration) at the start pose on the
extrapolated errors alone: the model ė = J u is known, so the critic can converge to P*(J₀)
before the arm moves instead of paying for a poor Ŵ₀ with error while it learns. With 0
iterations the critic starts from Ŵ₀ (200 + 200 samples, HJB cost with Q = 4·I: median cost 1.14×
and 1.20× the optimum instead of 1.010× and 1.015×, and about half the rollouts reach a velocity
limit; docs/model-error.md).

**What it is:** model-based policy iteration on the frozen-J ARE of the arm model, not learning
from data; ``snac-adaptive`` (:mod:`snac_gym.policies.snac_adaptive`) identifies the model.

Args of :class:`SNACHJBPolicy` are documented there; docs/snac.md has the measurements.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from snac_gym.control.optimality import (
    FrozenJacobianLQR,
    critic_error,
    hjb_residual,
    matrix_to_quadratic_weights,
    quadratic_weights_to_matrix,
)
from snac_gym.kernels.compiled import read_only_view
from snac_gym.policies.base import BasePolicy, positive_float
from snac_gym.policies.snac import CriticEpisode, QuadraticBasis


def _excitation_directions(dim: int) -> np.ndarray:
    """The n(n+1)/2 unit directions {eᵢ} ∪ {(eᵢ + eⱼ)/√2, i < j}: their dᵀPd fix a symmetric P."""
    eye = np.eye(dim)
    pairs = [(eye[i] + eye[j]) / math.sqrt(2.0) for i in range(dim) for j in range(i + 1, dim)]
    return np.vstack([eye, *pairs]) if pairs else eye


#: Relative margin of :func:`_certainly_above`: far above the rounding error of a Cholesky
#: factorisation and of ``eigh`` (both backward stable, errors of order n·ε·‖P‖ ≈ 1e-15·‖P‖).
CERTIFY_MARGIN = 1e-9


def _certainly_above(matrices: np.ndarray, floor: float) -> np.ndarray:
    """Rows of ``(B, n, n)`` symmetric ``matrices`` whose smallest eigenvalue is certainly ≥ ``floor``.

    Cholesky (LDLᵀ pivots, vectorised over the rows) of ``P − t I`` with ``t = floor + margin·max|P|``:
    all pivots positive means ``P − t I + E`` is positive definite for a backward error
    ``‖E‖ ≲ n ε ‖P‖``, so ``λ_min(P) ≥ floor + (margin − n ε)‖P‖``, and ``eigh``'s computed
    λ_min (equally backward stable) is ≥ ``floor`` too. A ``False`` row is merely undecided. The same operations as
    the compiled period's certificate (:func:`~snac_gym.kernels.hjb.periods`), which a draw's projection does not go
    through.
    """
    count, n, _ = matrices.shape
    shift = floor + CERTIFY_MARGIN * np.abs(matrices).max(axis=(1, 2))
    work = matrices - shift[:, None, None] * np.eye(n)
    positive = np.ones(count, dtype=bool)
    for k in range(n):
        pivot = work[:, k, k]
        positive &= pivot > 0
        safe = np.where(positive, pivot, 1.0)
        column = work[:, k + 1 :, k] / safe[:, None]
        work[:, k + 1 :, k + 1 :] -= column[:, :, None] * work[:, k, None, k + 1 :]
    return positive


class SNACHJBPolicy(CriticEpisode, BasePolicy):
    """SNAC whose critic is tuned by the HJB residual (module docstring), for reach and track.

    Args:
        env: The env (or :class:`~snac_gym.policies.base.PolicyContext`) to drive.
        Q: Error weight, ``(n, n)`` SPD or a length-n diagonal (default identity, the paper's).
        R: Effort weight, ``(m, m)`` SPD or a length-m diagonal (default identity, the paper's).
        q_scale: The effort knob (:attr:`effort_parameter`): the critic learns the optimum of
            ``q_scale·Q``, so the converged gain grows as √q_scale. Default 1: the paper's cost.
        learning_rate: α of the residual law, 1/s (one Euler step of α·Δt per period; ≤ 1/Δt).
        stabilising_rate: α_s of the eq. 19 term, 1/s.
        regularisation: ε of Γ, relative to the trace of the Gram matrix.
        min_eigenvalue: λ_floor of the projection of P̂ (cost per m² of error).
        warm_start_iterations: Full Kleinman steps of the residual law at the start pose, before
            the first command (0: the critic learns only while the arm moves).
        initial_weight_range: ``(low, high)`` of the uniform Ŵ₀ (default ``(0, 1)``).
        seed: Seed of Ŵ₀ used by ``reset(seed=None)``.

    Raises:
        ValueError: On a bad Q or R, or a non-positive or too large rate.

    Attributes:
        basis: The :class:`~snac_gym.policies.snac.QuadraticBasis` of e.
        critic_weights: The current Ŵ.
        internals: After ``act``: ``critic_weights`` (Ŵ after the update), ``critic_value``
            (V̂(e) with the weights that gave the command), ``hjb_residual`` (δ(e)).
    """

    effort_parameter = "q_scale"

    def __init__(
        self,
        env: Any,
        *,
        Q: Any = None,
        R: Any = None,
        q_scale: float = 1.0,
        learning_rate: float = 50.0,
        stabilising_rate: float = 100.0,
        regularisation: float = 1e-9,
        min_eigenvalue: float = 0.1,
        warm_start_iterations: int = 30,
        initial_weight_range: tuple[float, float] = (0.0, 1.0),
        seed: int | None = None,
    ) -> None:
        super().__init__(env)
        n, m = self.kinematics.task_dim, self.kinematics.n_joints
        self.task_dim, self.n_joints = n, m
        self.q_scale = positive_float("q_scale", q_scale)
        unscaled = FrozenJacobianLQR(Q, R, n, m)  # validates Q and R
        self.Q, self.R = self.q_scale * unscaled.Q, unscaled.R
        self.lqr = FrozenJacobianLQR(self.Q, self.R, n, m)
        self.R_inverse = self.lqr.R_inverse
        self.learning_rate = positive_float("learning_rate", learning_rate)
        if self.learning_rate * self.dt > 1.0:
            raise ValueError(
                f"learning_rate must be at most 1/dt = {1.0 / self.dt:g} 1/s (one full Newton step per period), "
                f"got {learning_rate}"
            )
        self.stabilising_rate = positive_float("stabilising_rate", stabilising_rate)
        self.regularisation = positive_float("regularisation", regularisation)
        self.min_eigenvalue = positive_float("min_eigenvalue", min_eigenvalue)
        if (
            isinstance(warm_start_iterations, bool)
            or not isinstance(warm_start_iterations, (int, np.integer))
            or not (0 <= warm_start_iterations <= 1000)
        ):
            raise ValueError(
                f"warm_start_iterations must be a whole number in [0, 1000], got {warm_start_iterations!r}"
            )
        self.warm_start_iterations = int(warm_start_iterations)
        low, high = map(float, initial_weight_range)
        if not (math.isfinite(low) and math.isfinite(high) and low <= high):
            raise ValueError(
                f"initial_weight_range must be finite (low, high) with low <= high, got {initial_weight_range}"
            )
        self.initial_weight_range = (low, high)
        self.basis = QuadraticBasis(n)
        self.directions = _excitation_directions(n)
        slices = self.layout.slices
        self._q, self._e, self._xdot_d = slices["q"], slices["e"], slices["xdot_d"]
        self._seed = seed
        self._rng = np.random.default_rng(seed)
        self.critic_weights = np.zeros(self.basis.size)
        self.batch_critic_weights: np.ndarray | None = None
        self._k = self._batch_k = 0
        self._ready = False

    # -- episodes -------------------------------------------------------------------------------
    def _initial_weights(self, rng: np.random.Generator) -> np.ndarray:
        weights: np.ndarray = self._project(self._initial_draw(rng)[None])[0]
        return weights

    def _initial_draw(self, rng: np.random.Generator) -> np.ndarray:
        """Ŵ₀ before its projection: uniform in :attr:`initial_weight_range`, ``(size,)``."""
        return rng.uniform(*self.initial_weight_range, size=self.basis.size)

    def _project(self, weights: np.ndarray, certain: np.ndarray | None = None) -> np.ndarray:
        """Rows ``(B, size)`` projected onto {P̂ ⪰ λ_floor I} (Frobenius: eigenvalues raised to the floor).

        Only the rows that :func:`_certainly_above` cannot clear (``certain``: its answer, where the caller has it)
        go through ``eigh`` (most rows are far above the floor); a row it clears is one whose eigh would leave it
        unchanged, so the result is the same, bit for bit, as decomposing every row.
        """
        if certain is None:
            certain = _certainly_above(quadratic_weights_to_matrix(weights, self.task_dim), self.min_eigenvalue)
        unclear = np.flatnonzero(~certain)
        if unclear.size == 0:
            return weights
        values, vectors = np.linalg.eigh(quadratic_weights_to_matrix(weights[unclear], self.task_dim))
        low = values[:, 0] < self.min_eigenvalue
        if not low.any():
            return weights
        raised = (vectors[low] * np.maximum(values[low], self.min_eigenvalue)[:, None, :]) @ np.swapaxes(
            vectors[low], -1, -2
        )
        weights = weights.copy()
        weights[unclear[low]] = matrix_to_quadratic_weights(raised)
        return weights

    def reset_batch(self, seeds: Sequence[int | None]) -> None:
        """Start ``len(seeds)`` episodes; episode i as ``reset(seed=seeds[i])`` of a fresh policy.

        Each episode draws its Ŵ₀ from its own seed; the draws are projected together (a row's
        projection does not depend on the others: the same bits as :meth:`_initial_weights`, 9x faster).
        """
        draws = [self._initial_draw(np.random.default_rng(self._seed if seed is None else seed)) for seed in seeds]
        self.batch_critic_weights = self._project(np.array(draws).reshape(len(seeds), self.basis.size))
        self._batch_k = 0
        self.internals = {}

    # -- the laws, on stacks of B episodes ---------------------------------------------------------
    def _periods(
        self,
        jacobians: np.ndarray,
        errors: np.ndarray,
        velocities: np.ndarray,
        weights: np.ndarray,
        factors: tuple[np.ndarray, ...] | None,
        step: float,
        stabilising: float,
    ) -> tuple[np.ndarray, ...]:
        """:func:`~snac_gym.kernels.hjb.periods` (``factors``: the LQR's of each J, for the tracking feed-forward;
        ``None``: no feed-forward). With ``stabilising`` 0 the increments are the residual law's alone."""
        from snac_gym.kernels.hjb import periods  # numba: imported where first needed

        jacobians = read_only_view(jacobians)
        _, n, m = jacobians.shape
        left, values, right = (
            (np.empty((0, m, n)), np.empty((0, n)), np.empty((0, n, n))) if factors is None else factors
        )
        return periods(
            jacobians, np.ascontiguousarray(errors, dtype=float), np.ascontiguousarray(velocities, dtype=float),
            np.ascontiguousarray(weights, dtype=float), self.R_inverse, left, values, right,
            read_only_view(self.velocity_limits), factors is not None, float(step), float(stabilising),
            self.directions, self.basis.first, self.basis.second, np.ascontiguousarray(self.Q, dtype=float),
            self.regularisation, self.min_eigenvalue, CERTIFY_MARGIN,
        )  # fmt: skip

    def _step(
        self, obs: np.ndarray, weights: np.ndarray, first: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Commands ``(B, m)``, the weights that gave them and the updated ones ``(B, size)``, and δ(e) ``(B,)``.

        Compiled (:func:`~snac_gym.kernels.hjb.periods`): eq. 15's command, then the residual law's step with eq.
        19's stabilising term where the feedback does not decrease J_s = ½eᵀe.
        """
        errors, velocities = obs[:, self._e], obs[:, self._xdot_d]
        jacobians = read_only_view(self._jacobians(obs))
        # J⁺_R = A diag(λ⁻¹) C from the LQR's factors: a J that lost rank drops that direction
        factors = self.lqr.factors(jacobians)[:3] if self.tracking else None
        weights = np.ascontiguousarray(weights)
        if first:  # the law run to convergence at the start pose before the first command moves the arm
            for _ in range(self.warm_start_iterations):
                *_, updated, certain = self._periods(jacobians, errors, velocities, weights, None, 1.0, 0.0)
                weights = self._project(updated, certain)
        command, _, residual, norms, updated, certain = self._periods(
            jacobians, errors, velocities, weights, factors, self.learning_rate * self.dt,
            self.stabilising_rate * self.dt,
        )  # fmt: skip
        return command, weights, self._project(updated, certain), residual * norms**2

    def _jacobians(self, obs: np.ndarray) -> np.ndarray:
        """The Jacobians ``(B, n, m)`` the critic and the command use at the observed θ: the model's."""
        return self.kinematics.jacobian_batch(obs[:, self._q])

    def _critic_jacobians(self, q: np.ndarray) -> np.ndarray:
        """The Jacobians the diagnostics measure the critic against (those of the problem it learns)."""
        return self.kinematics.jacobian_batch(q)

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)`` for ``(B, size)`` observations, row i as :meth:`act` of episode i.

        Raises:
            RuntimeError: If called before :meth:`reset_batch`.
        """
        if self.batch_critic_weights is None:
            raise RuntimeError("call reset_batch() before act_batch()")
        command, _, self.batch_critic_weights, _ = self._step(
            np.asarray(obs_batch, dtype=float), self.batch_critic_weights, first=self._batch_k == 0
        )
        self._batch_k += 1
        return command

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command (rad/s) for ``obs``; advances the critic one period.

        Raises:
            RuntimeError: If called before :meth:`reset`.
        """
        if not self._ready:
            raise RuntimeError("call reset() before act()")
        obs = np.asarray(obs, dtype=float)
        if obs.shape != (self.layout.size,):
            raise ValueError(f"observation must have shape ({self.layout.size},), got {obs.shape}")
        command, used, weights, residual = self._step(obs[None], self.critic_weights[None], first=self._k == 0)
        used = used[0]
        self.critic_weights = weights[0]
        self._k += 1
        error = obs[self._e]
        self.internals = {
            "critic_weights": self.critic_weights,
            "critic_value": float(self.basis(error) @ used),
            "hjb_residual": float(residual[0]),
        }
        row: np.ndarray = command[0]
        return row

    # -- diagnostics ------------------------------------------------------------------------------
    def critic_diagnostics(
        self, q: np.ndarray, e: np.ndarray, x_d: np.ndarray, xdot_d: np.ndarray, x_c: np.ndarray, weights: np.ndarray
    ) -> dict[str, np.ndarray]:
        """HJB residual δ(e) (eq. 9, :func:`~snac_gym.control.optimality.hjb_residual` with û = −R⁻¹JᵀP̂e, the
        feedback the critic commands), δ/eᵀQe and ``‖P̂ − P*(J)‖/‖P*‖`` at K logged rows.

        The critic is of the feedback problem ė = J u_fb for both tasks, so the same three hold
        for tracking (``x_d``, ``xdot_d`` and ``x_c`` are not needed; they keep the signature of
        :meth:`snac_gym.policies.snac.SNACPolicy.critic_diagnostics`).
        """
        e = np.asarray(e, dtype=float)
        jacobians = self._critic_jacobians(np.asarray(q, dtype=float))
        P = quadratic_weights_to_matrix(np.asarray(weights, dtype=float), self.task_dim)
        p_e = (P @ e[..., None])[..., 0]
        command = -(self.R_inverse @ np.swapaxes(jacobians, -1, -2) @ p_e[..., None])[..., 0]
        residual = hjb_residual(2.0 * p_e, jacobians, command, e, self.Q, self.R)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = residual / np.einsum("ki,ij,kj->k", e, self.Q, e)
        return {
            "hjb_residual": residual,
            "hjb_ratio": ratio,
            "critic_error": critic_error(P, self.lqr.solution(jacobians, at_singular="nan")),
        }
