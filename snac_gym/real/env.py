"""A Gymnasium env around a real (or rehearsed) UR arm, with the simulated env's spaces."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, cast

import gymnasium as gym
import numpy as np

from snac_gym.envs.core import TaskEnvCore, resolve_reference, validate_action, validate_q0
from snac_gym.real.connections import NORMAL, PROTECTIVE_STOP, PROTECTIVE_STOP_LOCKOUT, ArmConnection, ConnectionFailure
from snac_gym.real.recovery import LINK_RECOVERY, PROTECTIVE_STOP_RECOVERY, RecoveryLimits
from snac_gym.real.safety import SafetyLayer, SafetyLimits
from snac_gym.sampling import SampleSpace

if TYPE_CHECKING:
    from collections.abc import Callable

#: Seconds between two reads of the controller's state while waiting for a protective stop to clear.
_CLEAR_POLL = 0.05
#: Longest wait (s) after a refused command for the controller's state packages to show the stop that
#: refused it: the package read first may predate the stop. RTDE streams at 125-500 Hz, so on a real
#: controller the stop is in the next package, but the host's client process (or an emulated controller on
#: the same host) may not be scheduled for tens of milliseconds on a busy machine: 50 ms was once too short
#: there. Only a refusal that no stop explains waits it all, and the arm is stopped by then.
STOP_REPORT_WAIT_S = 0.25


class RealUREnv(TaskEnvCore):
    """A UR arm streaming joint velocities, with the same observation and action spaces as
    ``snac_gym/UR10Reach-v0`` / ``snac_gym/UR10EllipseTrack-v0``, so any policy drives it unchanged.

    Every step: the action is checked and clipped like the simulated env's, then shaped by the
    safety layer (speed scale, acceleration bound), sent, and the loop waits for the period's
    end before reading the state. The arm is stopped (``connection.stop()``, i.e. ``speedStop`` on
    ur_rtde, which returns once the arm is at rest) on every way out of an episode:

    * a stopping rule of :class:`~snac_gym.real.safety.SafetyLimits` fires (non-finite or stale
      state, task box, joint margin, late loop (with ``deadline_stop``), the controller's TCP away from the model's
      f(θ)) or the controller reports a protective or emergency stop: the episode terminates, ``info["safety"]`` says
      why and ``info["safety_state"]`` what the controller reports;
    * any exception inside ``step`` (a bad action, Ctrl-C, a lost connection, a bug), before it
      propagates; the reason is kept in :attr:`stop_reason`;
    * the episode is truncated (``max_steps``);
    * ``reset`` (the previous episode may have left the arm moving) and ``close``.

    After an episode ends no command is sent until the next ``reset``.

    ``reset(options={"q0": ...})`` checks q0 against the joint margins and the task box, then
    moves the arm there (a slow ``moveJ`` on hardware); without ``q0`` the episode starts where
    the arm is. Either way the arm is stopped and must be at rest before the episode starts, so
    the acceleration bound, which starts from u = 0, holds. The reference comes from the options
    exactly as in the simulated env (``target`` / ``ellipse``; paper's reference when options
    are given without one; random from ``sample_space`` without options).

    Args:
        task: A registered task's name.
        connection: An :class:`~snac_gym.real.connections.ArmConnection` (ur_rtde, simulated or dry run).
        safety: Safety limits (default: the conservative :class:`SafetyLimits`).
        max_steps: Episode length in control periods (default: the simulated env's episode in
            seconds, 8 s for reach, 20 s for track).
        success_tolerance: Error norm counted as success, m (default: the task's, 1 mm reach, 5 mm track).
        Q, R: Cost weights of the reward (default identity).
        sample_space: Space of random references.
        recovery: Whether and how far an episode resumes after a protective stop or a lost link
            (:class:`~snac_gym.real.recovery.RecoveryLimits`; default: never, the episode ends).

    A step after which the episode resumed has ``info["recovery"]``: what happened and how long
    the gap was (also in :attr:`recoveries`).

    Each step's ``info["speed_scaling"]`` is the controller's speed scaling (the pendant's speed
    slider; 1.0 where the connection reports none): below 1 the controller runs every command
    slower, so the arm trails the command by design; :meth:`timing` keeps its minimum.

    Attributes:
        periods: Measured durations (s) between consecutive commands in this episode.
        speed_scalings: The controller's speed scaling at reset and after each step.
        stop_reason: Why the arm was stopped mid-episode (a safety rule or an exception), or
            ``None``.
        recoveries: One dict per resumption in this episode: ``kind`` (``"protective stop"``
            or ``"lost link"``), ``step`` (the first step after the gap), ``cause``, ``gap_s``
            (wall time from the fault seen to the episode resumed) and how it was cleared.

    Raises:
        ValueError: On an unknown task or a non-positive ``max_steps`` / ``success_tolerance``.
    """

    metadata = {"render_modes": []}

    def __init__(
        self,
        task: str,
        connection: ArmConnection,
        safety: SafetyLimits | None = None,
        max_steps: int | None = None,
        success_tolerance: float | None = None,
        Q: np.ndarray | None = None,
        R: np.ndarray | None = None,
        sample_space: SampleSpace | None = None,
        recovery: RecoveryLimits | None = None,
    ) -> None:
        self._init_task(task, connection.kinematics, connection.dt, Q, R, success_tolerance, sample_space)
        self.connection = connection
        self.safety_limits = safety if safety is not None else SafetyLimits()
        self.safety = SafetyLayer(self.kinematics, self.safety_limits, self.dt)
        self.recovery = recovery if recovery is not None else RecoveryLimits()
        self.recoveries: list[dict[str, Any]] = []
        self._resumed = False
        # The simulated env's episode is episode_steps at 125 Hz: the same duration at this arm's rate.
        default_seconds = self.task.episode_steps / 125.0
        self.max_steps = int(max_steps) if max_steps is not None else int(round(default_seconds / self.dt))
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be a positive number of control periods, got {max_steps!r}")
        self.action_space = gym.spaces.Box(-self.velocity_limits, self.velocity_limits, dtype=np.float64)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(self.obs_layout.size,), dtype=np.float64)
        self.periods: list[float] = []
        self.speed_scalings: list[float] = []
        self._period_start: Any = None
        self._period_wall = 0.0
        self._episode_over = True
        self.stop_reason: str | None = None
        self._stop_request: str | None = None
        #: A :class:`~snac_gym.real.journal.StepJournal` that gets every period's row as it comes, or ``None``.
        self.journal: Any = None

    def _begin_period(self) -> None:
        # A period starts once the state is read, as in ur_rtde's initPeriod/waitPeriod loop, so the
        # policy's computation falls inside the period it is computed for.
        self._period_start = self.connection.start_period()
        self._period_wall = time.perf_counter()

    def _halt(self, reason: str) -> None:
        self.stop_reason = reason
        self._end_episode()

    def _end_episode(self) -> None:
        self._episode_over = True
        self.connection.stop()

    def _check_at_rest(self) -> None:
        _, qdot = self.connection.read_state()
        speed = float(np.max(np.abs(qdot)))
        if not speed < self.safety_limits.rest_speed:  # NaN-safe: a non-finite speed is not rest
            raise RuntimeError(
                f"the arm is still moving ({speed:.4f} rad/s, rest below {self.safety_limits.rest_speed} rad/s) "
                "after a stop: not starting an episode"
            )

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._episode_over = True  # nothing is sent until this reset has succeeded
        try:
            self.connection.stop()  # the previous episode may have left the arm moving
            state = self.connection.safety_state()
            if state != NORMAL:
                raise RuntimeError(
                    f"the controller reports {state}: clear it on the pendant before starting an episode"
                )
            reference = resolve_reference(self.task, self.kinematics, self.np_random, self.sample_space, options)
            q0 = None if options is None or options.get("q0") is None else validate_q0(self.kinematics, options["q0"])
            if q0 is not None:
                violation = self.safety.pose_violation(q0, self.kinematics.forward(q0))
                if violation is not None:  # checked before the arm moves there
                    raise ValueError(f"options['q0'] is outside the safety limits: {violation}")
                self.connection.move_to(q0)
            self._check_at_rest()
        except BaseException:
            self.connection.stop()
            raise
        self.reference = reference
        self.steps = 0
        self.periods = []
        self._last_command = np.zeros(self.kinematics.n_joints)
        self.stop_reason = None
        self._stop_request = None
        self.recoveries = []
        self._resumed = False
        self.safety.reset()
        q, qdot = self.connection.read_state()
        x = self.kinematics.forward(q)
        violation = self.safety.violation(q, qdot, x, self.connection.state_timestamp()) or self._tcp_mismatch(x)
        self.speed_scalings = [self._speed_scaling()]
        if violation is not None:
            self._halt(violation)
            raise RuntimeError(f"the arm starts outside the safety limits: {violation}")
        self._obs = self._pack(q, qdot)
        if self.journal is not None:
            self.journal.record(0, 0.0, None, self._obs, self.kinematics.n_joints, None, state, None)
        self._begin_period()
        self._episode_over = False
        info = self._reset_info(q0 if q0 is not None else q)
        return self._obs.copy(), {**info, "safety_state": state, "speed_scaling": self.speed_scalings[0]}

    def _tcp_mismatch(self, x_model: np.ndarray) -> str | None:
        """The FK check: the controller's reported TCP position against the model's f(θ) (if reported)."""
        reported = getattr(self.connection, "reported_tcp_position", None)
        return None if reported is None else self.safety.tcp_violation(x_model, reported())

    def _speed_scaling(self) -> float:
        """The controller's speed scaling (the pendant's slider) of the last read; 1.0 if not reported."""
        scaling = getattr(self.connection, "speed_scaling", None)
        return 1.0 if scaling is None else float(scaling())

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._obs is None:
            raise RuntimeError("call reset() before step()")
        if self.stop_reason is not None:
            raise RuntimeError(f"the arm was stopped ({self.stop_reason}); call reset() before sending commands")
        if self._episode_over:
            raise RuntimeError("the episode is over and the arm was stopped; call reset() before sending commands")
        try:
            return self._step(validate_action(action, self.velocity_limits))
        except BaseException as exc:  # a bad action, Ctrl-C, a lost connection, a bug: stop first, then report
            if not self._episode_over:
                self._halt(
                    f"{type(exc).__name__} during step: {str(exc).splitlines()[0] if str(exc) else ''}".rstrip(": ")
                )
            raise

    def stop_for(self, reason: str) -> None:
        """Stop the arm at the next step for ``reason``: a controller that has noticed it is diverging says so here.

        That step's command is not sent; the arm is halted as by a safety rule, the episode terminates
        and ``info["safety"]`` and :attr:`stop_reason` carry ``reason``.
        """
        self._stop_request = str(reason)

    def _step(self, u: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        reason: str | None  # why the arm stops this step (None: it does not)
        command = self.safety.shape(u, self._last_command)
        costs = self._step_costs(command)
        if self._stop_request is not None:
            reason, self._stop_request = self._stop_request, None
            self._halt(reason)
            return self._finish((costs[0], 0.0, 0.0), np.zeros_like(command), safety=reason)

        # A command computed after a stall is not sent: the state it was computed from is old, and
        # the controller's watchdog may already have stopped the arm.
        stalled = self.safety.stall(time.perf_counter() - self._period_wall) if self.steps > 0 else None
        if stalled is not None:
            self._halt(f"{stalled}: command not sent")
            return self._finish((costs[0], 0.0, 0.0), np.zeros_like(command), safety=self.stop_reason)
        try:
            self.connection.command(command)
            self.connection.end_period(self._period_start)
        except ConnectionFailure as exc:
            return self._after_lost_link(exc, costs, command)
        previous_start = self._period_wall
        self._begin_period()
        self.steps += 1
        self._last_command = command
        # Past its end, waitPeriod returns at once: a period longer than dt means the command came late.
        self.periods.append(self._period_wall - previous_start)
        # The first period also holds the policy's start-up, while the arm is still at rest; the
        # first after a resumption, the control script's re-upload.
        late = self.safety.record_period(self.periods[-1]) if self.steps > 1 and not self._resumed else None
        self._resumed = False
        try:
            q, qdot = self.connection.read_state()
        except ConnectionFailure as exc:
            return self._after_lost_link(exc, costs, command, counted=True)
        self._obs = self._pack(q, qdot)
        x = self._obs[self.obs_layout.slices["x"]]
        reason = late or self.safety.violation(q, qdot, x, self.connection.state_timestamp()) or self._tcp_mismatch(x)
        self.speed_scalings.append(self._speed_scaling())
        state = self.connection.safety_state()
        if reason is None and state != NORMAL:
            reason = f"controller reports {state}"
            if state == PROTECTIVE_STOP and self._may_recover():
                reason = self._resume(PROTECTIVE_STOP_RECOVERY, reason)
                if reason is None:
                    return self._finish(costs, command, safety=None, safety_state=NORMAL, recovery=self.recoveries[-1])
        if reason is not None:
            self._halt(reason)
        return self._finish(costs, command, safety=reason, safety_state=state)

    def _state_after_refusal(self) -> tuple[np.ndarray, np.ndarray, str]:
        """Joint state and safety state once the packages show why the controller refused a command.

        A stop refuses the command at once, but the last state package may have left the
        controller just before it: read again while the state says normal, for at most
        :data:`STOP_REPORT_WAIT_S` (a refusal still unexplained then is taken as a lost link).
        """
        deadline = time.monotonic() + STOP_REPORT_WAIT_S
        while True:
            q, qdot = self.connection.read_state()
            state = self.connection.safety_state()
            if state != NORMAL or time.monotonic() >= deadline:
                return q, qdot, state
            time.sleep(0.001)

    def _may_recover(self) -> bool:
        return len(self.recoveries) < self.recovery.max_recoveries

    def _after_lost_link(
        self, exc: ConnectionFailure, costs: tuple[float, float, float], command: np.ndarray, counted: bool = False
    ) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Resume if allowed (the step then counts, its gap marked); else ``exc`` propagates.

        A client still serving means the link is up and the controller refused the command. If the
        controller reports a stop, the command was in flight when the stop paused its program: a
        protective stop is resumed as one where recoveries are allowed, and any other stop ends the
        episode as a controller stop, as when the host reads it first. A client given up (the link
        lost) is replaced by a new one first.
        """
        reconnect = getattr(self.connection, "reconnect", None)
        recoverable = reconnect is not None and self._may_recover()
        seen = time.monotonic()
        if getattr(self.connection, "failure", None) is None:
            try:
                q, qdot, state = self._state_after_refusal()
            except ConnectionFailure:
                raise exc from None
            if state == NORMAL:
                raise exc
            cause = f"controller reports {state}"
            if state != PROTECTIVE_STOP or not recoverable:
                self._obs = self._pack(q, qdot)
                self._halt(cause)
                return self._finish((costs[0], 0.0, 0.0), np.zeros_like(command), safety=cause, safety_state=state)
            kind, cleared_by = PROTECTIVE_STOP_RECOVERY, ""
        elif not recoverable:
            raise exc
        else:
            self.connection.stop()  # the client is gone: this only records that the controller's watchdog stops the arm
            try:
                attempts = cast("Callable[[float], int]", reconnect)(self.recovery.reconnect_timeout)  # recoverable
            except ConnectionFailure as again:
                raise ConnectionFailure(f"{exc}; {again}") from exc
            kind, cause, cleared_by = LINK_RECOVERY, str(exc), f"reconnected ({attempts} attempts)"
        if not counted:
            self.steps += 1
        reason = self._resume(kind, cause, seen=seen, cleared_by=cleared_by)
        if reason is not None:
            self._halt(reason)
            return self._finish(costs, command, safety=reason, safety_state=self.connection.safety_state())
        return self._finish(costs, command, safety=None, safety_state=NORMAL, recovery=self.recoveries[-1])

    def _resume(self, kind: str, cause: str, seen: float | None = None, cleared_by: str = "") -> str | None:
        """Stop, wait for the fault to clear, re-check as at reset, and resume; else why not.

        Nothing is sent in here. On success the state just read becomes the observation, the
        command starts again from rest, and the period restarts.
        """
        seen = time.monotonic() if seen is None else seen
        self.connection.stop()
        if kind == PROTECTIVE_STOP_RECOVERY:
            waited = self._wait_until_cleared(seen)
            if waited.startswith("not cleared"):
                return f"{cause}; {waited}"
            cleared_by = waited
        q, qdot, stamp, failure = self._fresh_state()
        x = self.kinematics.forward(q)
        state = self.connection.safety_state()
        speed = float(np.max(np.abs(qdot)))
        self.safety.reset()
        failure = (
            failure
            or (f"the controller reports {state}" if state != NORMAL else None)
            or (None if speed < self.safety_limits.rest_speed else f"the arm is still moving ({speed:.4f} rad/s)")
            or self.safety.violation(q, qdot, x, stamp)
            or self._tcp_mismatch(x)
        )
        if failure is not None:
            return f"{cause}; not resumed after the {kind}: {failure}"
        self.recoveries.append({
            "kind": kind, "step": self.steps, "cause": cause, "cleared_by": cleared_by,
            "gap_s": time.monotonic() - seen,
        })  # fmt: skip
        self._last_command = np.zeros(self.kinematics.n_joints)
        self._obs = self._pack(q, qdot)
        self._resumed = True
        self._begin_period()
        return None

    def _wait_until_cleared(self, seen: float) -> str:
        """Wait for the protective stop to clear; how it cleared, or ``"not cleared ..."``."""
        limits = self.recovery
        deadline = seen + limits.clear_timeout
        unlock_at = seen + PROTECTIVE_STOP_LOCKOUT if limits.unlock_protective_stop else np.inf
        answers: list[str] = []
        while True:
            self.connection.read_state()
            state = self.connection.safety_state()
            if state == NORMAL:
                return "unlocked from the dashboard" if unlock_at == -np.inf else "cleared on the pendant"
            if state != PROTECTIVE_STOP:
                return f"not cleared: the controller now reports {state}"
            now = time.monotonic()
            if now >= deadline:
                refused = f" (dashboard: {answers[-1]!r})" if answers else ""
                return f"not cleared within {limits.clear_timeout:g} s{refused}"
            if now >= unlock_at:
                answer = self.connection.unlock_protective_stop()  # type: ignore[attr-defined]
                if answer is None:
                    unlock_at = -np.inf  # released: the next packages show it
                else:
                    answers.append(answer)
                    unlock_at = now + 1.0
            time.sleep(_CLEAR_POLL)

    def _fresh_state(self) -> tuple[np.ndarray, np.ndarray, float, str | None]:
        """A state package newer than the first one read now (the controller is streaming again)."""
        q, qdot = self.connection.read_state()
        first = self.connection.state_timestamp()
        deadline = time.monotonic() + self.recovery.fresh_state_timeout
        while True:
            q, qdot = self.connection.read_state()
            stamp = self.connection.state_timestamp()
            if stamp > first:
                return q, qdot, stamp, None
            if time.monotonic() >= deadline:
                return q, qdot, stamp, f"no fresh state within {self.recovery.fresh_state_timeout:g} s"
            self.connection.end_period(self.connection.start_period())  # one period, nothing sent

    def _finish(
        self,
        costs: tuple[float, float, float],
        command: np.ndarray,
        safety: str | None,
        safety_state: str = NORMAL,
        recovery: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        info = self._step_info(costs, command)
        info.update(safety=safety, safety_state=safety_state, speed_scaling=self.speed_scalings[-1])
        if recovery is not None:
            info["recovery"] = dict(recovery)
        if self.journal is not None:
            period = self.periods[-1] if len(self.periods) == self.steps and self.steps else None
            n_joints = self.kinematics.n_joints
            self.journal.record(
                self.steps, self.steps * self.dt, period, self._obs, n_joints, command, safety_state, safety
            )
        terminated = safety is not None
        truncated = not terminated and self.steps >= self.max_steps
        if truncated:
            self._end_episode()
        assert self._obs is not None  # within an episode (step() checks)
        return self._obs.copy(), -(costs[0] + costs[1]), terminated, truncated, info

    def timing(self) -> dict[str, float]:
        """Loop period statistics of the episode so far (ms): mean, std, p50, p99, max; the number of
        periods, of late ones (over (1 + ``deadline_slack``) × dt) and of stalled ones (over ``max_period``),
        counted whether or not the safety layer's ``deadline_stop`` stops the arm on them."""
        if not self.periods:
            return {}
        periods = np.asarray(self.periods) * 1e3
        return {
            "periods": len(periods),
            "period_ms_mean": float(periods.mean()),
            "period_ms_std": float(periods.std()),
            "period_ms_p50": float(np.percentile(periods, 50)),
            "period_ms_p99": float(np.percentile(periods, 99)),
            "period_ms_max": float(periods.max()),
            "jitter_ms_max": float(np.abs(periods - self.dt * 1e3).max()),
            "late_periods": int(np.sum(periods > (1 + self.safety_limits.deadline_slack) * self.dt * 1e3)),
            "stalled_periods": int(np.sum(periods > self.safety_limits.max_period * 1e3)),
            "speed_scaling_min": float(min(self.speed_scalings, default=1.0)),
        }

    def close(self) -> None:
        if not self._episode_over and self.stop_reason is None:
            self.stop_reason = "closed mid-episode"
        self._episode_over = True
        self.connection.close()
