"""SNAC that adapts to a wrong arm model: the HJB-tuned critic on a Jacobian identified from measurements.

``snac-hjb`` (:mod:`snac_gym.policies.snac_hjb`) learns its critic P̂ by policy iteration on the
frozen-Jacobian problem ė = J u, with J from the arm model. When that model is wrong (a joint's
zero, a link length, the tool frame: ``--model-error``), the critic converges to the optimum of
the wrong problem, and nothing in the measured data reaches it. This controller keeps the same
critic, command and weight law (eqs. 15 and 19 as in ``snac-hjb``) and replaces the model's J by
Ĵ from an **identifier** that learns, from the measured stream (θₖ, xₖ), what the model gets
wrong: a separate identifier beside the critic, as in Bhasin et al. (Automatica 2013), here a
parametric one.

**Identifier.** The correction is parameterised by the family of errors the model can have
(:mod:`snac_gym.model_error`), c = (c_a ∈ Rᵐ, c_s, c_t ∈ R³) (joint offsets, a scale of every
link, a tool-point offset in the tool frame), applied to the model's forward kinematics f, tool
rotation R and Jacobians J_v, J_ω at φ = θ + c_a::

    x̂(θ; c) = (1 + c_s) f(φ) + R(φ) c_t
    Ĵ(θ; c)  = ∂x̂/∂θ = (1 + c_s) J_v(φ) − [R(φ) c_t]ₓ J_ω(φ)
    H        = ∂x̂/∂c = [Ĵ, f(φ), R(φ)]                                  (3 × (m + 4))

The family is closed under inversion, so the true arm is x̂(·; c*) for some c*: the identification
is exact, not an approximation. c is estimated by an extended Kalman filter on the measurement
xₖ = x̂(θₖ; c*) (a recursive Gauss–Newton with the prior c ~ N(0, Σ₀)): each control step
r = xₖ − x̂(θₖ; ĉ), ĉ ← ĉ + K r, Σ ← (I − K H) Σ, K = Σ Hᵀ(H Σ Hᵀ + σ²I)⁻¹. The critic and the
command then use Ĵ(θₖ; ĉ) wherever ``snac-hjb`` uses J.

**What converges, and under which condition.** (i) The identifier: recursive Gauss–Newton on an
exactly parameterised, smooth regression converges locally to c* (Ljung 1979, the EKF as a
parameter estimator) when the regressor is persistently exciting, Σ_{k}^{k+N} H_kᵀH_k ⪰ αI on
windows of N steps; then Ĵ → J. Along one reach path the regressors span few directions: ĉ then
converges to *a* c that matches the arm along the path travelled (x̂ = x and Ĵu = Ju there), which
is what the command needs, not to c*. The condition is checked at run time, not assumed:
``identifier.excitation()`` is λ_min of the accumulated information Σ HᵀH/σ², and
``internals["model_residual"]`` the measured prediction error ‖xₖ − x̂(θₖ; ĉ)‖ before the update.
(ii) The critic: with Ĵ fixed, the weight law is Kleinman's iteration on the frozen-Ĵ ARE, which
converges to P*(Ĵ) from any stabilising start (Kleinman 1968); with Ĵ = J that is the true
problem's optimum. (iii) The closed loop (certainty equivalence): ė = −J R⁻¹ĴᵀP̂ e decreases ‖e‖
when J R⁻¹ĴᵀP̂ has a positive definite symmetric part, which holds once ‖Ĵ − J‖ is small; while
the error grows (eᵀĴu_fb > 0 by the estimate) eq. 19's stabilising term acts, as in ``snac-hjb``.
Nothing here proves a bound on the transient before ĉ has converged; docs/model-error.md
measures it.

The position x must be *measured* (the evaluator's plant, the PyBullet env, an external tracker
on a real arm): on a real arm x computed from the encoders through the same wrong model carries
no information about the error, and the identifier then stays at ĉ = 0 (``snac-hjb`` exactly).

Args of :class:`SNACAdaptivePolicy` are documented there.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from snac_gym.policies.base import positive_float
from snac_gym.policies.snac_hjb import SNACHJBPolicy

#: Default prior standard deviations: joint offsets (rad), link scale (relative), tool offset (m).
PRIOR_JOINT_OFFSET, PRIOR_LINK_SCALE, PRIOR_TOOL_OFFSET = 0.5, 0.05, 0.05
#: Default measurement noise of x, m.
MEASUREMENT_NOISE = 1e-4
#: Default random-walk standard deviation of every parameter per step: lets the filter forget the
#: information it linearised at early, poor estimates (on a dithered pose, Ĵ's error after 1000
#: steps: 8.5e-5 without, 1.1e-5 with 1e-4; the tracking results did not change).
PROCESS_NOISE = 1e-4
#: Gauss–Newton re-linearisations of each measurement update (1: the plain EKF, whose tracking
#: succeeded on 9 of 10 ellipses where 3 succeeded on all 10; docs/model-error.md).
ITERATIONS = 3


def _skew_rows(vectors: np.ndarray) -> np.ndarray:
    """``[v]ₓ`` of every row of ``(B, 3)`` vectors, ``(B, 3, 3)``."""
    x, y, z = vectors[:, 0], vectors[:, 1], vectors[:, 2]
    zero = np.zeros_like(x)
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)


class KinematicIdentifier:
    """The EKF of the module docstring over B episodes at once.

    Args:
        kinematics: The (possibly wrong) arm model the correction is relative to.
        prior: Standard deviations of the prior on (joint offsets, link scale, tool offset).
        noise: Standard deviation σ of the measured position, m.
        iterations: Re-linearisations of each measurement update (the iterated EKF).
        process_noise: Random-walk standard deviation of every parameter per step.
    """

    def __init__(
        self, kinematics: Any, prior: tuple[float, float, float], noise: float, iterations: int = ITERATIONS,
        process_noise: float = PROCESS_NOISE,
    ) -> None:
        self.kinematics = kinematics
        self.iterations = int(iterations)
        m = kinematics.n_joints
        self.n_joints, self.size = m, m + 4
        self.prior = np.diag(np.concatenate([np.full(m, prior[0] ** 2), [prior[1] ** 2], np.full(3, prior[2] ** 2)]))
        self.noise = float(noise)
        self.process_noise = float(process_noise) ** 2 * np.eye(self.size)
        self.reset(1)

    def reset(self, count: int) -> None:
        """Start ``count`` episodes at ĉ = 0, Σ = Σ₀."""
        self.params = np.zeros((count, self.size))
        self.covariance = np.broadcast_to(self.prior, (count, self.size, self.size)).copy()
        self.information = np.zeros((count, self.size, self.size))
        self.residual = np.zeros(count)

    def _model(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """x̂, Ĵ and H at θ (rows) for the current ĉ."""
        m = self.n_joints
        # One episode's estimate may serve many rows (a demo log's diagnostics, at the final ĉ).
        params = np.broadcast_to(self.params, (len(q), self.size))
        offsets, scale, tool = params[:, :m], params[:, m], params[:, m + 1 :]
        f, rotation, linear, angular = self.kinematics.frame_batch(q + offsets)
        tool_point = np.einsum("bij,bj->bi", rotation, tool)
        predicted = (1.0 + scale)[:, None] * f + tool_point
        jacobian = (1.0 + scale)[:, None, None] * linear - _skew_rows(tool_point) @ angular
        regressor = np.concatenate([jacobian, f[:, :, None], rotation], axis=2)
        return predicted, jacobian, regressor

    def update(self, q: np.ndarray, x: np.ndarray) -> np.ndarray:
        """One iterated-EKF step on the measurements (θ, x) of every episode; returns Ĵ at θ after it.

        The measurement update is re-linearised at its own result ``iterations`` times (the
        iterated EKF: Gauss–Newton on the prior plus this measurement), so that a first residual of
        centimetres does not move ĉ by a linearisation's overshoot.
        """
        prior_params, covariance = self.params, self.covariance + self.process_noise
        eye = self.noise**2 * np.eye(3)
        for iteration in range(self.iterations):
            predicted, _, regressor = self._model(q)
            if iteration == 0:
                self.residual = np.linalg.norm(x - predicted, axis=1)
            innovation = regressor @ covariance @ np.swapaxes(regressor, 1, 2) + eye
            gain = np.swapaxes(np.linalg.solve(innovation, regressor @ covariance), 1, 2)  # Σ Hᵀ S⁻¹
            residual = x - predicted - (regressor @ (prior_params - self.params)[:, :, None])[:, :, 0]
            self.params = prior_params + (gain @ residual[:, :, None])[:, :, 0]
        covariance = covariance - gain @ regressor @ covariance
        self.covariance = 0.5 * (covariance + np.swapaxes(covariance, 1, 2))
        self.information += np.swapaxes(regressor, 1, 2) @ regressor / self.noise**2
        return self._model(q)[1]

    def jacobians(self, q: np.ndarray) -> np.ndarray:
        """Ĵ at θ for the current ĉ, without an update."""
        return self._model(q)[1]

    def excitation(self) -> np.ndarray:
        """λ_min of the accumulated information Σ HᵀH/σ² of each episode (the excitation condition)."""
        return np.linalg.eigvalsh(self.information)[:, 0]


class SNACAdaptivePolicy(SNACHJBPolicy):
    """``snac-hjb`` on the identified Jacobian Ĵ (module docstring), for reach and track.

    Args:
        env: The env (or :class:`~snac_gym.policies.base.PolicyContext`) to drive; its kinematics
            is the arm *model* (the evaluator's ``--model-error`` makes it wrong).
        Q, R, q_scale: As for ``snac-hjb`` (the cost the critic learns; ``q_scale`` is the effort knob).
        prior_joint_offset, prior_link_scale, prior_tool_offset: Prior standard deviations of the
            correction's parts (rad, relative, m).
        measurement_noise: σ of the measured position, m.
        **kwargs: The other arguments of :class:`~snac_gym.policies.snac_hjb.SNACHJBPolicy`.

    Attributes:
        identifier: The :class:`KinematicIdentifier` (its ``params`` are ĉ per episode).
        internals: After :meth:`act`, those of ``snac-hjb`` plus ``model_residual`` (m, before the
            update) and ``model_correction`` (ĉ); ``identifier.excitation()`` gives λ_min of Σ HᵀH/σ²
            on demand (an eigendecomposition: not in every control step).
    """

    #: Scalar internals the episode log records as columns (:mod:`snac_gym.rollout.log`).
    logged_internals = ("model_residual",)

    def __init__(
        self,
        env: Any,
        Q: Any = None,
        R: Any = None,
        q_scale: float = 1.0,
        prior_joint_offset: float = PRIOR_JOINT_OFFSET,
        prior_link_scale: float = PRIOR_LINK_SCALE,
        prior_tool_offset: float = PRIOR_TOOL_OFFSET,
        measurement_noise: float = MEASUREMENT_NOISE,
        **kwargs: Any,
    ) -> None:
        super().__init__(env, Q=Q, R=R, q_scale=q_scale, **kwargs)
        if self.task_dim != 3:
            raise ValueError("snac-adaptive identifies the position kinematics: it runs the position tasks only")
        prior = tuple(
            positive_float(name, value)
            for name, value in (
                ("prior_joint_offset", prior_joint_offset),
                ("prior_link_scale", prior_link_scale),
                ("prior_tool_offset", prior_tool_offset),
            )
        )
        self.identifier = KinematicIdentifier(self.kinematics, prior, positive_float("measurement_noise", measurement_noise))
        self._x = self.layout.slices["x"]

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self.identifier.reset(1)

    def reset_batch(self, seeds: Sequence[int | None]) -> None:
        super().reset_batch(seeds)
        self.identifier.reset(len(seeds))

    def _jacobians(self, obs: np.ndarray) -> np.ndarray:
        """Ĵ after one identifier step on the measured (θ, x) of this period."""
        return self.identifier.update(obs[:, self._q], obs[:, self._x])

    def act(self, obs: np.ndarray) -> np.ndarray:
        command = super().act(obs)
        self.internals.update(
            {
                "model_residual": float(self.identifier.residual[0]),
                "model_correction": self.identifier.params[0].copy(),
            }
        )
        return command

    def _critic_jacobians(self, q: np.ndarray) -> np.ndarray:
        """Ĵ for the diagnostics: the critic learns the problem on Ĵ (it cannot know J). In the
        evaluator, the estimate of each episode at that step; on a demo log (rows of one episode,
        after it ended), the final estimate for every row."""
        return self.identifier.jacobians(q)


__all__ = ["KinematicIdentifier", "SNACAdaptivePolicy"]
