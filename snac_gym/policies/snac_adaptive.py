"""SNAC that adapts to a wrong arm model: the HJB-tuned critic on a Jacobian identified from measurements.

``snac-hjb`` (:mod:`snac_gym.policies.snac_hjb`) learns its critic P̂ by policy iteration on the
frozen-Jacobian problem ė = J u, with J from the arm model. When that model is wrong (a joint's
zero, a link length, the tool frame: ``--model-error``), the critic converges to the optimum of
the wrong problem, and nothing in the measured data reaches it. This controller keeps the same
critic, command and weight law (eqs. 15 and 19 as in ``snac-hjb``) and replaces the model's J by
Ĵ from an **identifier** that learns, from the measured stream (θₖ, xₖ), what the model gets
wrong: a separate identifier beside the critic, as in Bhasin et al. (Automatica 2013), here a
parametric one over every geometric error an arm can have.

**Identifier.** The correction is not told which error the model has. It is a rigid error at every
fixed transform of the chain, the complete family of geometric errors of a serial arm: a twist
c₀ = (τ₀, ρ₀) ∈ R⁶ at the base and cⱼ = (τⱼ, ρⱼ) ∈ R⁶ after joint j's motion, j = 1..m, applied as
Eⱼ = (Exp(ρⱼ), τⱼ) in the chain of the model's placements Mⱼ and joint motions::

    T(θ; c) = E₀ · M₁ Rot(a₁, θ₁) E₁ · M₂ Rot(a₂, θ₂) E₂ ⋯ Mₘ Rot(aₘ, θₘ) Eₘ,   x̂(θ; c) = T(θ; c) · p_tool

An error before joint j's motion (a joint zero, an axis tilt) is an error after joint j − 1's; an
error of the tool frame is one after the last joint's; so every placement error, including another
robot's link lengths (``model=ur5``), is some c* (6(m + 1) = 42 numbers for a 6-joint arm). What
it cannot represent: a joint's gear ratio or encoder scale, compliance, backlash, anything that
depends on load or speed. Its derivatives are exact, for frame k at (R_k⁻, R_k⁺ = R_k⁻Exp(ρ_k), p_k⁺)
before and after its correction::

    Ĵ(θ; c) = [zⱼ × (x̂ − oⱼ)]ⱼ                        (eq. 2 on the corrected chain)
    H_k     = ∂x̂/∂c_k = [R_k⁻,  −[x̂ − p_k⁺]ₓ R_k⁺ J_r(ρ_k)]     (3 × 6 per frame; J_r: SO(3)'s right Jacobian)

Position measurements see only a part of c (a translation along a joint's axis and the next
joint's offset trade against each other): the prior c ~ N(0, Σ₀), Σ₀ = diag(0.5 m, 0.05 rad)² per
frame, holds the directions the data do not reach, and the estimate is the most probable c given
the prior and the data, not c*. c is estimated by an iterated extended Kalman filter on the
measurement xₖ = x̂(θₖ; c*) (a recursive Gauss–Newton): each control step
r = xₖ − x̂(θₖ; ĉ), ĉ ← ĉ + K r, Σ ← (I − K H) Σ, K = Σ Hᵀ(H Σ Hᵀ + σ²I)⁻¹, re-linearised three
times. The critic and the command then use Ĵ(θₖ; ĉ) wherever ``snac-hjb`` uses J.

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

**Divergence.** Because nothing bounds that transient, the controller watches itself
(:class:`DivergenceMonitor`) and says when a bound is crossed, instead of running away silently.
An episode *diverges* when, at some step k,

* the error grew: ‖eₖ‖ > ‖e₀‖ + 5 cm;
* the progress fell short of the prediction: ‖eₖ‖ > 2 cm and, over the last 0.5 s, the measured
  decrease of ‖e‖ fell short of the one the controller predicted for its own commands
  (ê = e + (Ĵu − ẋ_d)Δt) by more than 1 cm and half the prediction: slow progress that the
  controller expected (a velocity limit, a direction J hardly moves in) is not a divergence, and
  a Ĵ that points the arm the wrong way is;
* no progress: ‖eₖ‖ > 2 cm and ‖e‖ fell by less than 1 mm over the last 2 s (a wrong Ĵ whose
  command vanishes, Ĵᵀe = 0, predicts no progress either);
* the model failed: the prediction residual ‖xₖ − x̂(θₖ; ĉ)‖ > 1 cm after the first 0.2 s (the
  complete family fits any rigid error to the measurement noise, so a residual this size means a
  fault of the measurement or of the model class).
* too slow: ‖eₖ‖ > 5 cm and, at the rate ‖e‖ fell over the last 2 s, closing it would take more
  than 6 s (half a reach's horizon): progress the controller may well have predicted (a pose near a
  singularity, where the LQR's slowest mode is 2σ_min(J)), but an episode that would end centimetres off,
  and that must say so.

From that step the episode's command is the fallback, a stop (u = 0, ``fallback="stop"``), and
its ``diverged`` flag is raised: a log column, ``diverged`` and ``diverged_time`` in the
evaluator's results, and on a real arm a stop through the safety layer
(:meth:`~snac_gym.real.env.RealUREnv.stop_for`) with the reason in the run's ``stop_reason``.
The bounds are arguments; ``fallback="none"`` keeps the command and only raises the flag.

The position x must be *measured* (the evaluator's plant, the PyBullet env, an external tracker
on a real arm): on a real arm x computed from the encoders through the same wrong model carries
no information about the error, and the identifier then stays at ĉ = 0 (``snac-hjb`` exactly).

Args of :class:`SNACAdaptivePolicy` are documented there.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from snac_gym.model.kinematics import leaf_chain
from snac_gym.policies.base import positive_float
from snac_gym.policies.snac_hjb import SNACHJBPolicy

#: Default prior standard deviations of every frame's correction: translation (m), rotation (rad). 0.5 m: another
#: arm's links (the UR3's are 0.37 m shorter than the UR10's); 0.1 m held a UR3 model's correction 3.7σ out, and
#: the filter tracked 37 of 50 ellipses where 0.5 m tracks 50 (docs/model-error.md, "Another arm's model").
PRIOR_TRANSLATION, PRIOR_ROTATION = 0.5, 0.05
#: Default measurement noise of x, m.
MEASUREMENT_NOISE = 1e-4
#: Default random-walk standard deviation of every parameter per step: lets the filter forget the
#: information it linearised at early, poor estimates (chosen with the earlier 10-parameter identifier,
#: where on a dithered pose Ĵ's error after 1000 steps fell from 8.5e-5 to 1.1e-5; kept, not re-tuned).
PROCESS_NOISE = 1e-4
#: Gauss–Newton re-linearisations of each measurement update (1: the plain EKF; with the earlier
#: 10-parameter identifier it tracked 9 of 10 test ellipses where 3 tracked all 10; kept, not re-tuned).
ITERATIONS = 3
#: Divergence bounds (:class:`DivergenceMonitor`): growth past ‖e₀‖ (m); the floor below which nothing stalls (m);
#: the window (s) and least shortfall (m) of the measured progress against the predicted one; the window (s) and
#: least progress (m) of the no-progress rule; the prediction residual (m) after a settling time (s); the error (m)
#: above which the progress over the no-progress window must close the error within the longest time to go (s).
DIVERGENCE_GROWTH, DIVERGENCE_FLOOR = 0.05, 0.02
DIVERGENCE_WINDOW, DIVERGENCE_SHORTFALL, DIVERGENCE_PATIENCE, DIVERGENCE_LEAST_PROGRESS = 0.5, 0.01, 2.0, 0.001
DIVERGENCE_RESIDUAL, DIVERGENCE_SETTLE = 0.01, 0.2
DIVERGENCE_SLOW_FLOOR, DIVERGENCE_TIME_TO_GO = 0.05, 6.0
#: What a diverged episode commands.
FALLBACKS = ("stop", "none")


class GeometricIdentifier:
    """The iterated EKF of the module docstring over the complete geometric correction, B episodes at once.

    Args:
        kinematics: The (possibly wrong) arm model the correction is relative to.
        prior: Standard deviations of the prior on each frame's (translation in m, rotation in rad).
        noise: Standard deviation σ of the measured position, m.
        iterations: Re-linearisations of each measurement update (the iterated EKF).
        process_noise: Random-walk standard deviation of every parameter per step.
    """

    def __init__(
        self,
        kinematics: Any,
        prior: tuple[float, float],
        noise: float,
        iterations: int = ITERATIONS,
        process_noise: float = PROCESS_NOISE,
    ) -> None:
        self.kinematics = kinematics
        self.iterations = int(iterations)
        steps, offset = leaf_chain(kinematics)
        steps = steps[::-1]  # base first
        if not all(revolute for _, _, _, revolute, _ in steps):
            raise ValueError("snac-adaptive's identifier needs an arm of revolute joints")
        # The chain for the compiled model (snac_gym/kernels/identifier.py): placements, axes, columns, tool point.
        self._chain = (
            np.array([rotation for rotation, _, _, _, _ in steps], dtype=float).reshape(-1, 3, 3),
            np.array([translation for _, translation, _, _, _ in steps], dtype=float).reshape(-1, 3),
            np.array([axis for _, _, axis, _, _ in steps], dtype=float).reshape(-1, 3),
            np.array([column for _, _, _, _, column in steps], dtype=np.int64),
            np.asarray(offset, dtype=float).reshape(3),
        )
        self.n_joints = kinematics.n_joints
        self.frames = len(steps) + 1  # the base and each joint's frame after its motion
        self.size = 6 * self.frames
        block = np.concatenate([np.full(3, prior[0] ** 2), np.full(3, prior[1] ** 2)])
        self.prior = np.diag(np.tile(block, self.frames))
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
        """x̂, Ĵ and H at θ (rows) for the current ĉ: the chain with every frame's correction in it."""
        from snac_gym.kernels.identifier import corrected_chain  # numba: imported where first needed

        # One episode's estimate may serve many rows (a demo log's diagnostics, at the final ĉ).
        params = np.ascontiguousarray(np.broadcast_to(self.params, (len(q), self.size)))
        return corrected_chain(np.ascontiguousarray(q, dtype=float), params, *self._chain)

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


class DivergenceMonitor:
    """The bounds an adaptive controller watches itself by, over B episodes (module docstring, "Divergence").

    Args:
        dt: Control period, s.
        growth: An episode diverges when ‖eₖ‖ exceeds ‖e₀‖ by this much, m.
        floor: Below this error, m, no episode is said to stall.
        window: The window over which the measured progress is held against the predicted one, s.
        shortfall: The least shortfall of the measured progress below the predicted one over a window
            that counts, m (it must also be half the predicted progress or more).
        patience: The window of the no-progress rule, s.
        least_progress: The decrease of ‖e‖ over ``patience`` below which an episode above the floor
            has made no progress, m.
        residual: An episode diverges when the model's prediction residual exceeds this, m, once the
            identifier has had ``settle`` s to correct the first error of the model.
        settle: Time before the residual bound applies, s.
        slow_floor: Above this error, m, an episode must be closing it fast enough:
        time_to_go: the longest time, s, the error above ``slow_floor`` may take to close at the rate it fell over
            the last ``patience`` s (‖eₖ‖·patience > time_to_go·(‖eₖ₋ₚ‖ − ‖eₖ‖): too slow).
    """

    def __init__(
        self,
        dt: float,
        growth: float = DIVERGENCE_GROWTH,
        floor: float = DIVERGENCE_FLOOR,
        window: float = DIVERGENCE_WINDOW,
        shortfall: float = DIVERGENCE_SHORTFALL,
        patience: float = DIVERGENCE_PATIENCE,
        least_progress: float = DIVERGENCE_LEAST_PROGRESS,
        residual: float = DIVERGENCE_RESIDUAL,
        settle: float = DIVERGENCE_SETTLE,
        slow_floor: float = DIVERGENCE_SLOW_FLOOR,
        time_to_go: float = DIVERGENCE_TIME_TO_GO,
    ) -> None:
        self.growth, self.floor, self.shortfall, self.least_progress = growth, floor, shortfall, least_progress
        self.slow_floor, self.time_to_go, self.patience_time = slow_floor, time_to_go, patience
        self.residual_bound = residual
        self.window = max(1, round(window / dt))
        self.patience = max(1, round(patience / dt))
        self.settle = max(1, round(settle / dt))
        self.reset(1)

    def reset(self, count: int) -> None:
        """Start ``count`` episodes, none diverged."""
        self.k = 0
        self.initial = np.zeros(count)
        self.previous = np.zeros(count)
        self.predicted = np.zeros((self.window, count))  # ‖eⱼ‖ − ‖êⱼ₊₁‖ of the last ``window`` steps, a ring
        self.measured = np.zeros((self.window, count))  # ‖eⱼ‖ − ‖eⱼ₊₁‖ of the same steps
        self.history = np.zeros((self.patience, count))  # ‖e‖ of the last ``patience`` steps, a ring
        self.diverged = np.zeros(count, dtype=bool)
        self.step = np.full(count, -1)  # the step each episode was flagged at (−1: never)
        self.reason = np.full(count, "", dtype=object)

    def describe(self, episode: int) -> str:
        """Why and when episode ``episode`` was flagged (empty if it was not)."""
        if not self.diverged[episode]:
            return ""
        return f"{self.reason[episode]} at step {self.step[episode]}"

    def check(self, error_norms: np.ndarray, residuals: np.ndarray, predicted_norms: np.ndarray) -> np.ndarray:
        """Update with this step's ‖eₖ‖, the prediction residuals and the controller's own prediction ‖êₖ₊₁‖ of the
        next error under the command it is about to send; returns the episodes flagged (ever)."""
        k = self.k
        if k == 0:
            self.initial = error_norms.copy()
        else:
            self.measured[(k - 1) % self.window] = self.previous - error_norms
        predicted, measured = self.predicted.sum(axis=0), self.measured.sum(axis=0)
        above = error_norms > self.floor
        rules = {
            "error grew": error_norms > self.initial + self.growth,
            # Slow progress the controller predicted (a velocity limit, a singular direction) is not a divergence.
            "progress fell short of the prediction": (k >= self.window)
            & above
            & (predicted - measured > np.maximum(self.shortfall, 0.5 * predicted)),
            "no progress": (k >= self.patience)
            & above
            & (self.history[k % self.patience] - error_norms < self.least_progress),
            "prediction residual": (k >= self.settle) & (residuals > self.residual_bound),
            # Progress, but too slow to close a large error within the time to go (however well predicted).
            "too slow": (k >= self.patience)
            & (error_norms > self.slow_floor)
            & (error_norms * self.patience_time > self.time_to_go * (self.history[k % self.patience] - error_norms)),
        }
        for reason, fired in rules.items():
            new = fired & ~self.diverged
            if new.any():
                self.diverged |= new
                self.step[new] = k
                self.reason[new] = reason
        self.predicted[k % self.window] = error_norms - predicted_norms
        self.history[k % self.patience] = error_norms
        self.previous = error_norms
        self.k += 1
        return self.diverged


class SNACAdaptivePolicy(SNACHJBPolicy):
    """``snac-hjb`` on the identified Jacobian Ĵ (module docstring), for reach and track, watching itself.

    Args:
        env: The env (or :class:`~snac_gym.policies.base.PolicyContext`) to drive; its kinematics
            is the arm *model* (the evaluator's ``--model-error`` makes it wrong).
        Q, R, q_scale: As for ``snac-hjb`` (the cost the critic learns; ``q_scale`` is the effort knob).
        prior_translation, prior_rotation: Prior standard deviations of every frame's correction
            (m, rad): how far the model may be from the arm.
        measurement_noise: σ of the measured position, m.
        fallback: What a diverged episode commands from then on: ``"stop"`` (zero velocity, the
            default) or ``"none"`` (keep the adaptive command; the flag is still raised).
        divergence_growth, divergence_floor, divergence_window, divergence_shortfall, divergence_patience,
        divergence_least_progress, divergence_residual, divergence_slow_floor, divergence_time_to_go: The bounds of
            :class:`DivergenceMonitor` (m, m, s, m, s, m, m, m, s).
        **kwargs: The other arguments of :class:`~snac_gym.policies.snac_hjb.SNACHJBPolicy`.

    Attributes:
        identifier: The :class:`GeometricIdentifier` (its ``params`` are ĉ per episode).
        monitor: The :class:`DivergenceMonitor` (its ``diverged``, ``step`` and ``reason`` per episode).
        internals: After :meth:`act`, those of ``snac-hjb`` plus ``model_residual`` (m, before the
            update), ``model_correction`` (ĉ), ``diverged`` (1.0 once flagged, else 0.0) and ``divergence``
            (which bound and when, empty while none was crossed);
            ``identifier.excitation()`` gives λ_min of Σ HᵀH/σ² on demand.
    """

    #: Scalar internals the episode log records as columns (:mod:`snac_gym.rollout.log`).
    logged_internals = ("model_residual", "diverged")

    def __init__(
        self,
        env: Any,
        Q: Any = None,
        R: Any = None,
        q_scale: float = 1.0,
        prior_translation: float = PRIOR_TRANSLATION,
        prior_rotation: float = PRIOR_ROTATION,
        measurement_noise: float = MEASUREMENT_NOISE,
        fallback: str = "stop",
        divergence_growth: float = DIVERGENCE_GROWTH,
        divergence_floor: float = DIVERGENCE_FLOOR,
        divergence_window: float = DIVERGENCE_WINDOW,
        divergence_shortfall: float = DIVERGENCE_SHORTFALL,
        divergence_patience: float = DIVERGENCE_PATIENCE,
        divergence_least_progress: float = DIVERGENCE_LEAST_PROGRESS,
        divergence_residual: float = DIVERGENCE_RESIDUAL,
        divergence_slow_floor: float = DIVERGENCE_SLOW_FLOOR,
        divergence_time_to_go: float = DIVERGENCE_TIME_TO_GO,
        **kwargs: Any,
    ) -> None:
        super().__init__(env, Q=Q, R=R, q_scale=q_scale, **kwargs)
        if self.task_dim != 3:
            raise ValueError("snac-adaptive identifies the position kinematics: it runs the position tasks only")
        if fallback not in FALLBACKS:
            raise ValueError(f"fallback must be one of {', '.join(FALLBACKS)}, got {fallback!r}")
        self.fallback = fallback
        prior = (
            positive_float("prior_translation", prior_translation),
            positive_float("prior_rotation", prior_rotation),
        )
        self.identifier = GeometricIdentifier(
            self.kinematics, prior, positive_float("measurement_noise", measurement_noise)
        )
        self.monitor = DivergenceMonitor(
            self.dt, **{name: positive_float(f"divergence_{name}", value) for name, value in (
                ("growth", divergence_growth), ("floor", divergence_floor), ("window", divergence_window),
                ("shortfall", divergence_shortfall), ("patience", divergence_patience),
                ("least_progress", divergence_least_progress), ("residual", divergence_residual),
                ("slow_floor", divergence_slow_floor), ("time_to_go", divergence_time_to_go))},
        )  # fmt: skip
        self._x = self.layout.slices["x"]

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self.identifier.reset(1)
        self.monitor.reset(1)

    def reset_batch(self, seeds: Sequence[int | None]) -> None:
        super().reset_batch(seeds)
        self.identifier.reset(len(seeds))
        self.monitor.reset(len(seeds))

    def _jacobians(self, obs: np.ndarray) -> np.ndarray:
        """Ĵ after one identifier step on the measured (θ, x) of this period."""
        self._last_jacobians = self.identifier.update(obs[:, self._q], obs[:, self._x])
        return self._last_jacobians

    def _watched(self, obs: np.ndarray, command: np.ndarray) -> np.ndarray:
        """The command after the divergence check of this step (the identifier has just run)."""
        errors = obs[:, self._e]
        # The controller's own prediction of the next error: ê = e + (Ĵu − ẋ_d)Δt.
        predicted = errors + ((self._last_jacobians @ command[..., None])[..., 0] - obs[:, self._xdot_d]) * self.dt
        diverged = self.monitor.check(
            np.linalg.norm(errors, axis=1), self.identifier.residual, np.linalg.norm(predicted, axis=1)
        )
        if self.fallback == "stop" and diverged.any():
            command = np.where(diverged[:, None], 0.0, command)
        return command

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        obs_batch = np.asarray(obs_batch, dtype=float)
        return self._watched(obs_batch, super().act_batch(obs_batch))

    def _act(self, obs: np.ndarray) -> np.ndarray:
        command: np.ndarray = self._watched(np.asarray(obs, dtype=float)[None], super()._act(obs)[None])[0]
        self.internals.update(
            {
                "model_residual": float(self.identifier.residual[0]),
                "model_correction": self.identifier.params[0].copy(),
                "diverged": float(self.monitor.diverged[0]),
                "divergence": self.monitor.describe(0),
            }
        )
        return command

    def episode_flags(self) -> dict[str, np.ndarray]:
        """Per-episode flags for the results: ``diverged`` (bool) and ``diverged_step`` (−1: never)."""
        return {"diverged": self.monitor.diverged.copy(), "diverged_step": self.monitor.step.copy()}

    def _critic_jacobians(self, q: np.ndarray) -> np.ndarray:
        """Ĵ for the diagnostics: the critic learns the problem on Ĵ (it cannot know J). In the
        evaluator, the estimate of each episode at that step; on a demo log (rows of one episode,
        after it ended), the final estimate for every row."""
        return self.identifier.jacobians(q)


__all__ = ["DivergenceMonitor", "GeometricIdentifier", "SNACAdaptivePolicy"]
