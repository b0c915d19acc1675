"""A Gymnasium env around a real (or rehearsed) UR arm, with the simulated env's spaces."""

from __future__ import annotations

import math
import time
from typing import Any

import gymnasium as gym
import numpy as np

from snac_gym.cost import quadratic_form
from snac_gym.envs.core import resolve_reference, validate_action, validate_q0
from snac_gym.envs.tasks import TASKS
from snac_gym.observation import ObservationLayout
from snac_gym.real.backends import NORMAL, ArmBackend
from snac_gym.real.safety import SafetyLayer, SafetyLimits
from snac_gym.references import Reference
from snac_gym.sampling import SampleSpace


class RealUREnv(gym.Env):
    """A UR arm streaming joint velocities, with the same observation and action spaces as
    ``snac_gym/UR10Reach-v0`` / ``snac_gym/UR10EllipseTrack-v0``, so any policy drives it unchanged.

    Every step: the action is checked and clipped like the simulated env's, then shaped by the
    safety layer (speed scale, acceleration bound), sent, and the loop waits for the period's
    end before reading the state. The arm is stopped (``backend.stop()``, i.e. ``speedStop`` on
    ur_rtde) and the episode terminates when a stopping rule of
    :class:`~snac_gym.real.safety.SafetyLimits` fires or the controller reports a protective or
    emergency stop (``info["safety"]`` says why, ``info["safety_state"]`` what the controller
    reports); it is also stopped on ``close()`` and on any exception inside ``step`` (Ctrl-C
    included) before the exception propagates. After a stop no command is sent until the next
    ``reset``.

    ``reset(options={"q0": ...})`` moves the arm to q0 first (a slow ``moveJ`` on hardware);
    without ``q0`` the episode starts where the arm is. The reference comes from the options
    exactly as in the simulated env (``target`` / ``ellipse``; paper's reference when options
    are given without one; random from ``sample_space`` without options).

    Args:
        task: ``"reach"`` or ``"track"``.
        backend: An :class:`~snac_gym.real.backends.ArmBackend` (ur_rtde, simulated or dry run).
        safety: Safety limits (default: the conservative :class:`SafetyLimits`).
        max_steps: Episode length in control periods (default 8 s for reach, 20 s for track).
        success_tolerance: Error norm counted as success, m (1 mm reach, 5 mm track).
        Q, R: Cost weights of the reward (default identity).
        sample_space: Space of random references.

    Attributes:
        periods: Measured durations (s) between consecutive commands in this episode.
    """

    metadata = {"render_modes": []}

    def __init__(
        self,
        task: str,
        backend: ArmBackend,
        safety: SafetyLimits | None = None,
        max_steps: int | None = None,
        success_tolerance: float | None = None,
        Q: np.ndarray | None = None,
        R: np.ndarray | None = None,
        sample_space: SampleSpace | None = None,
    ) -> None:
        if task not in TASKS:
            raise ValueError(f"task must be one of {sorted(TASKS)}, got {task!r}")
        self.task = TASKS[task]()
        self.task_name = task
        self.backend = backend
        self.kinematics = backend.kinematics
        self.dt = float(backend.dt)
        self.safety_limits = safety if safety is not None else SafetyLimits()
        self.safety = SafetyLayer(self.kinematics, self.safety_limits, self.dt)
        default_seconds = 8.0 if task == "reach" else 20.0
        self.max_steps = int(max_steps) if max_steps is not None else int(round(default_seconds / self.dt))
        self.success_tolerance = (
            float(success_tolerance) if success_tolerance is not None else (1e-3 if task == "reach" else 5e-3)
        )
        self.Q, self.R = Q, R
        self.sample_space = sample_space if sample_space is not None else SampleSpace.for_robot(self.kinematics)
        self.velocity_limits = self.kinematics.velocity_limits.copy()
        self.obs_layout = ObservationLayout(self.kinematics.n_joints, self.kinematics.task_dim)
        self.action_space = gym.spaces.Box(-self.velocity_limits, self.velocity_limits, dtype=np.float64)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(self.obs_layout.size,), dtype=np.float64)
        self.reference: Reference = self.task.paper()
        self.steps = 0
        self.periods: list[float] = []
        self._obs: np.ndarray | None = None
        self._last_command = np.zeros(self.kinematics.n_joints)
        self._period_start: Any = None
        self._period_wall = 0.0
        self.stop_reason: str | None = None

    @property
    def time(self) -> float:
        return self.steps * self.dt

    def _observe(self) -> np.ndarray:
        q, qdot = self.backend.read_state()
        x_d, xdot_d = self.reference.position_and_velocity(self.time)
        return self.obs_layout.pack(q, qdot, self.kinematics.forward(q), x_d, xdot_d, self.reference.centre)

    def _begin_period(self) -> None:
        # A period starts once the state is read, as in ur_rtde's initPeriod/waitPeriod loop, so the
        # policy's computation falls inside the period it is computed for.
        self._period_start = self.backend.start_period()
        self._period_wall = time.perf_counter()

    def _halt(self, reason: str) -> None:
        self.stop_reason = reason
        self.backend.stop()

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        state = self.backend.safety_state()
        if state != NORMAL:
            raise RuntimeError(f"the controller reports {state}: clear it on the pendant before starting an episode")
        reference = resolve_reference(self.task, self.kinematics, self.np_random, self.sample_space, options)
        q0 = None if options is None or options.get("q0") is None else validate_q0(self.kinematics, options["q0"])
        try:
            if q0 is not None:
                self.backend.move_to(q0)
        except BaseException:
            self._halt("exception while moving to the start pose")
            raise
        self.reference = reference
        self.steps = 0
        self.periods = []
        self._last_command = np.zeros(self.kinematics.n_joints)
        self.stop_reason = None
        self.safety.reset()
        self._obs = self._observe()
        self._begin_period()
        fields = self.obs_layout.unpack(self._obs)
        violation = self.safety.violation(fields.q, fields.x)
        if violation is not None:
            self._halt(violation)
            raise RuntimeError(f"the arm starts outside the safety limits: {violation}")
        return self._obs.copy(), {"error": fields.e.copy(), "reference": reference.to_dict(), "safety_state": state}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._obs is None:
            raise RuntimeError("call reset() before step()")
        if self.stop_reason is not None:
            raise RuntimeError(f"the arm was stopped ({self.stop_reason}); call reset() before sending commands")
        u = validate_action(action, self.velocity_limits)
        try:
            return self._step(u)
        except BaseException as exc:  # Ctrl-C, lost connection, a bug: stop first, then report
            if self.stop_reason is None:
                self._halt(f"{type(exc).__name__} during step")
            raise

    def _step(self, u: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        command = self.safety.shape(u, self._last_command)
        error_before = self._obs[self.obs_layout.slices["e"]]
        cost_error = float(quadratic_form(error_before, self.Q))
        cost_effort = float(quadratic_form(command, self.R))
        cost_smoothness = float(quadratic_form((command - self._last_command) / self.dt, self.R))

        self.backend.command(command)
        self.backend.end_period(self._period_start)
        previous_start = self._period_wall
        self._begin_period()
        self.steps += 1
        self._last_command = command
        # Past its end, waitPeriod returns at once: a period longer than dt means the command came late.
        self.periods.append(self._period_wall - previous_start)
        late = self.safety.record_period(self.periods[-1])
        self._obs = self._observe()
        if late is not None:
            self._halt(late)
            return self._finish(cost_error, cost_effort, cost_smoothness, command, safety=late)

        fields = self.obs_layout.unpack(self._obs)
        reason = self.safety.violation(fields.q, fields.x)
        state = self.backend.safety_state()
        if state != NORMAL:
            reason = f"controller reports {state}"
        if reason is not None:
            self._halt(reason)
        return self._finish(cost_error, cost_effort, cost_smoothness, command, safety=reason, safety_state=state)

    def _finish(
        self, cost_error: float, cost_effort: float, cost_smoothness: float, command: np.ndarray,
        safety: str | None, safety_state: str = NORMAL,
    ) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        error = self._obs[self.obs_layout.slices["e"]]
        success = bool(error @ error <= self.success_tolerance**2)
        info = {
            "error": error.copy(), "error_norm": math.sqrt(error @ error), "cost_error": cost_error,
            "cost_effort": cost_effort, "cost_smoothness": cost_smoothness, "command": command.copy(),
            "t": self.time, "is_success": success, "safety": safety, "safety_state": safety_state,
        }
        terminated = safety is not None
        truncated = not terminated and self.steps >= self.max_steps
        return self._obs.copy(), -(cost_error + cost_effort), terminated, truncated, info

    def timing(self) -> dict[str, float]:
        """Loop period statistics of the episode so far (ms): mean, std, p50, p99, max, and late count."""
        if not self.periods:
            return {}
        periods = np.asarray(self.periods) * 1e3
        return {
            "period_ms_mean": float(periods.mean()),
            "period_ms_std": float(periods.std()),
            "period_ms_p50": float(np.percentile(periods, 50)),
            "period_ms_p99": float(np.percentile(periods, 99)),
            "period_ms_max": float(periods.max()),
            "jitter_ms_max": float(np.abs(periods - self.dt * 1e3).max()),
            "late_periods": int(np.sum(periods > (1 + self.safety_limits.deadline_slack) * self.dt * 1e3)),
        }

    def close(self) -> None:
        self.backend.close()
