"""SNAC with a critic learned from data: off-policy integral RL (Jiang & Jiang, Automatica 2012) on the arm.

``snac-hjb`` (:mod:`snac_gym.policies.snac_hjb`) learns its critic P̂ by policy iteration on the
arm *model*'s frozen-Jacobian problem ė = J u: its critic is as right as the model. This
controller learns P and the gain from the *measured* error and command alone, by the data-driven
policy iteration of :mod:`snac_gym.control.irl`: for the arm A = 0 and B = J, and J is unknown to the
learner.

**Episode.** Each episode runs in two phases:

1. *Exploring* (the first ``learning_time`` s, L = round(learning_time/Δt) periods): the initial
   stabilising policy plus an exploration signal::

       u = sat(J_m⁺ ẋ_d − K₀ e + ε(t)),   K₀ = R⁻¹ J_mᵀ P*(J_m)  (the model's LQR gain at θ₀)
       εⱼ(t) = a·v_maxⱼ Σᵢ sin(ωᵢⱼ t + φᵢⱼ)/√(N/2)   (N sinusoids a joint, RMS a·v_maxⱼ)

   J_m is the arm model's Jacobian at the start pose θ₀ (the only use of the model: with
   ``--model-error`` it is wrong, and so are K₀ and the feed-forward; K₀ still stabilises while
   J J_mᵀ keeps a positive definite symmetric part). ωᵢⱼ ~ U(``frequency_range``) rad/s and φᵢⱼ
   are drawn from the reset seed. The measured errors e₀…e_L, the applied commands u₀…u_{L−1}
   (after the scaling into the limits, what the arm was given) and the drift w = −ẋ_d are kept.
2. *Learned* (from step L on): the windows of ``window_steps`` periods
   (:func:`~snac_gym.control.irl.windows_from_samples`, ė = J u + w with w = −ẋ_d the measured drift)
   go to Algorithm 1 (:func:`~snac_gym.control.irl.policy_iteration`) from K₀, which returns P and K with
   K ≈ R⁻¹ JᵀP (eq. 7) and no use of J. Then::

       u = sat(Ĵ⁺_R ẋ_d − K e),   Ĵ = P⁻¹ Kᵀ R   (eq. 7 read backwards: Jᵀ = R K P⁻¹)

   so the tracking feed-forward uses the Jacobian the data imply, not the model's.

With ``relearn_every = N > 0`` the exploration never stops and every N periods after the first
learning the iteration is run again on the last L periods, from the current K (a sliding window:
the arm's J changes as θ moves, the learned P follows). With 0 (the default) the episode learns
once: after the reach the data would carry no excitation but ε.

**What it costs.** The exploration is paid in the cost: ∫ uᵀRu of ε and the error it causes,
during the first ``learning_time`` s (the whole episode with ``relearn_every``). The learned P is
that of a frozen J, averaged over the poses the arm passed while exploring; at the later poses of
a long reach it is not P*(J(θ)) (``snac-hjb`` follows J(θ) through the model). docs/irl.md has
the measurements.

**When the learning fails** (eq. 13's rank not met, a non-finite or not positive definite P) the
episode keeps K₀ and the model's feed-forward; ``internals["learned"]`` says which happened.

Position tasks (reach, track) only: the data-driven iteration is the paper's, for a linear
system; the orientation error of the pose tasks is not.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from snac_gym.common.validation import whole_number
from snac_gym.control.irl import policy_iteration, windows_from_samples
from snac_gym.control.optimality import FrozenJacobianLQR, positive_definite_weight
from snac_gym.policies.base import BasePolicy, positive_float, scale_rows_into_limits


class SNACIRLPolicy(BasePolicy):
    """A critic and gain learned from measured (e, u) by off-policy integral RL (module docstring).

    Args:
        env: The env (or :class:`~snac_gym.policies.base.PolicyContext`) to drive.
        Q: Error weight, ``(n, n)`` SPD or a length-n diagonal (default identity).
        R: Effort weight, ``(m, m)`` SPD or a length-m diagonal (default identity).
        q_scale: The effort knob (:attr:`effort_parameter`): the optimum of ``q_scale·Q`` is learned.
        learning_time: s of exploration before the first learning (L periods, at least
            ``n(n+1)/2 + mn`` windows are needed: eq. 13).
        window_steps: Control periods per data window.
        exploration: a, the RMS of each joint's exploration signal as a fraction of its velocity limit.
        sinusoids: N, sinusoids in each joint's exploration signal.
        frequency_range: ``(low, high)`` of their frequencies, rad/s (below π/Δt, the sampling's limit).
        relearn_every: Periods between re-learnings on a sliding window of the last L periods
            (0: learn once; the exploration then stops after learning).
        initial_gain_scale: c of K₀ = c·R⁻¹J_mᵀP*(J_m): below 1 the arm moves less while it explores,
            so that J changes less over the data (the iteration assumes a frozen J).
        tolerance: ε of the iteration's stopping rule ‖P_k − P_{k−1}‖ ≤ ε.
        max_iterations: Least-squares solves at most per learning.
        seed: Seed of the exploration used by ``reset(seed=None)``.

    Raises:
        ValueError: On a bad Q or R, a pose task, or an argument out of its range (named).

    Attributes:
        internals: After ``act``: ``learned`` (whether the gain in use was learned), ``iterations``
            (of the last learning), ``exploring`` (whether ε was added this step).
    """

    effort_parameter = "q_scale"

    def __init__(
        self,
        env: Any,
        *,
        Q: Any = None,
        R: Any = None,
        q_scale: float = 1.0,
        learning_time: float = 0.4,
        window_steps: int = 1,
        exploration: float = 0.05,
        sinusoids: int = 10,
        frequency_range: tuple[float, float] = (1.0, 60.0),
        relearn_every: int = 0,
        initial_gain_scale: float = 1.0,
        tolerance: float = 1e-6,
        max_iterations: int = 30,
        seed: int | None = None,
    ) -> None:
        super().__init__(env)
        if self.kinematics.task_dim != 3 or getattr(self.kinematics, "task_error", None) is not None:
            raise ValueError(f"snac-irl drives the 3-D position tasks (reach, track), not {self.task!r}")
        n, m = self.kinematics.task_dim, self.kinematics.n_joints
        self.task_dim, self.n_joints = n, m
        self.q_scale = positive_float("q_scale", q_scale)
        self.Q, self.R = self.q_scale * positive_definite_weight(Q, n, "Q"), positive_definite_weight(R, m, "R")
        self.lqr = FrozenJacobianLQR(self.Q, self.R, n, m)
        self.learning_time = positive_float("learning_time", learning_time)
        self.window_steps = whole_number("window_steps", window_steps, 1, 1000)
        self.learning_steps = max(1, round(self.learning_time / self.dt))
        needed = n * (n + 1) // 2 + m * n
        if self.learning_steps // self.window_steps < needed:
            raise ValueError(
                f"learning_time of {learning_time} s makes {self.learning_steps // self.window_steps} windows of "
                f"{self.window_steps} periods; eq. 13 needs at least {needed}"
            )
        self.exploration = positive_float("exploration", exploration)
        self.sinusoids = whole_number("sinusoids", sinusoids, 1, 1000)
        low, high = map(float, frequency_range)
        if not (math.isfinite(low) and math.isfinite(high) and 0 <= low < high <= math.pi / self.dt):
            raise ValueError(
                f"frequency_range must be (low, high) with 0 <= low < high <= π/dt = {math.pi / self.dt:g}, "
                f"got {frequency_range}"
            )
        self.frequency_range = (low, high)
        self.relearn_every = whole_number("relearn_every", relearn_every, 0, 10**9)
        self.initial_gain_scale = positive_float("initial_gain_scale", initial_gain_scale)
        self.tolerance = positive_float("tolerance", tolerance)
        self.max_iterations = whole_number("max_iterations", max_iterations, 1, 1000)
        slices = self.layout.slices
        self._q, self._e, self._xdot_d = slices["q"], slices["e"], slices["xdot_d"]
        self._seed = seed
        self._batch: dict[str, Any] | None = None

    # -- episodes -------------------------------------------------------------------------------
    def _draw(self, seed: int | None) -> tuple[np.ndarray, np.ndarray]:
        """Frequencies and phases ``(m, N)`` of one episode's exploration, from its seed."""
        rng = np.random.default_rng(self._seed if seed is None else seed)
        frequencies = rng.uniform(*self.frequency_range, size=(self.n_joints, self.sinusoids))
        phases = rng.uniform(0.0, 2.0 * math.pi, size=(self.n_joints, self.sinusoids))
        return frequencies, phases

    def reset_batch(self, seeds: Sequence[int | None]) -> None:
        """Start ``len(seeds)`` episodes; episode i as ``reset(seed=seeds[i])`` of a fresh policy."""
        draws = [self._draw(seed) for seed in seeds]
        self._batch = {
            "frequencies": np.array([d[0] for d in draws]),  # (B, m, N)
            "phases": np.array([d[1] for d in draws]),
            "k": 0,
            "errors": [], "commands": [], "drifts": [],
            "gain": None, "initial_gain": None, "jacobian": None,
            "learned": np.zeros(len(seeds), dtype=bool), "iterations": np.zeros(len(seeds), dtype=int),
        }  # fmt: skip
        self.internals = {}

    def reset(self, seed: int | None = None) -> None:
        """Start an episode (the exploration drawn from ``seed``, else from the constructor's)."""
        self.reset_batch([seed])

    def _exploration(self, t: float) -> np.ndarray:
        """ε(t) of every episode, ``(B, m)``: RMS ``exploration``·v_max per joint."""
        b = self._batch
        assert b is not None  # act_batch() checked it
        waves = np.sin(b["frequencies"] * t + b["phases"]).sum(axis=-1) / math.sqrt(self.sinusoids / 2.0)
        noise: np.ndarray = self.exploration * self.velocity_limits * waves
        return noise

    def _learn(self) -> None:
        """Algorithm 1 on the last L periods of each episode; keeps the current gain where it fails."""
        b = self._batch
        assert b is not None  # act_batch() checked it
        L = self.learning_steps
        errors = np.array(b["errors"][-(L + 1) :])  # (L+1, B, n): e at the start of each period and after the last
        commands = np.array(b["commands"][-L:])  # (L, B, m)
        drifts = np.array(b["drifts"][-L:])
        for i in range(errors.shape[1]):
            data = windows_from_samples(errors[:, i], commands[:, i], self.dt, self.window_steps, drifts[:, i])
            try:
                result = policy_iteration(
                    data, self.Q, self.R, b["gain"][i], tolerance=self.tolerance, max_iterations=self.max_iterations
                )
            except ValueError:  # eq. 13's rank not met: keep the gain
                continue
            P, K = result.P_final, result.K_final
            if not (np.all(np.isfinite(P)) and np.all(np.isfinite(K)) and np.linalg.eigvalsh(P)[0] > 0):
                continue
            b["gain"][i] = K
            b["jacobian"][i] = np.linalg.solve(P, K.T @ self.R)  # Ĵ = P⁻¹KᵀR (eq. 7: K = R⁻¹JᵀP)
            b["learned"][i] = True
            b["iterations"][i] = result.iterations

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)`` for ``(B, size)`` observations, row i as :meth:`act` of episode i.

        Raises:
            RuntimeError: If called before :meth:`reset_batch`.
        """
        b = self._batch
        if b is None:
            raise RuntimeError("call reset_batch() before act_batch()")
        obs = np.asarray(obs_batch, dtype=float)
        errors, velocities = obs[:, self._e], obs[:, self._xdot_d]
        k = b["k"]
        if k == 0:  # K₀ from the model at θ₀: the only use of the arm model
            model_jacobian = self.kinematics.jacobian_batch(obs[:, self._q])
            b["initial_gain"] = self.initial_gain_scale * self.lqr.gain(model_jacobian)
            b["gain"] = b["initial_gain"].copy()
            b["jacobian"] = model_jacobian.copy()
        b["errors"].append(errors)
        L = self.learning_steps
        if k == L or (self.relearn_every and k > L and (k - L) % self.relearn_every == 0):
            self._learn()
        exploring = k < L or self.relearn_every > 0
        gain = b["gain"]
        command = -(gain @ errors[..., None])[..., 0]
        if self.tracking:  # Ĵ⁺_R ẋ_d: the data's Jacobian once learned, the model's before
            command += (self.lqr.weighted_pseudoinverse(b["jacobian"]) @ velocities[..., None])[..., 0]
        if exploring:
            command += self._exploration(k * self.dt)
        command = scale_rows_into_limits(command, self.velocity_limits)
        b["commands"].append(command)
        b["drifts"].append(-velocities)  # ė = J u − ẋ_d: w = −ẋ_d
        if not self.relearn_every and k >= L:  # learned once: the record is no longer needed
            b["errors"], b["commands"], b["drifts"] = b["errors"][-1:], b["commands"][-1:], b["drifts"][-1:]
        elif len(b["commands"]) > L + 1:
            del b["errors"][0], b["commands"][0], b["drifts"][0]
        b["k"] = k + 1
        self.internals = {"learned": b["learned"].copy(), "iterations": b["iterations"].copy(), "exploring": exploring}
        return command

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command (rad/s) for ``obs``; records the data and learns at step L.

        Raises:
            RuntimeError: If called before :meth:`reset`.
        """
        if self._batch is None:
            raise RuntimeError("call reset() before act()")
        command: np.ndarray = self.act_batch(np.asarray(obs, dtype=float)[None])[0]
        self.internals = {
            key: (value[0] if isinstance(value, np.ndarray) else value) for key, value in self.internals.items()
        }
        return command
