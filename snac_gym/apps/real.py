"""One episode on a real UR arm (or its rehearsal): what ``snac-gym real`` does, importable."""

from __future__ import annotations

import json
import re
import signal
import sys
import traceback
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from snac_gym.apps.demo import write_demo_outputs
from snac_gym.common._signals import STOP_SIGNALS as COMMAND_STOP_SIGNALS
from snac_gym.common._signals import SignalGuard, TerminationSignal
from snac_gym.common._signals import stop_signals_raise as _stop_signals_raise
from snac_gym.common.outputs import usable_out_folder, write_text_whole, write_whole
from snac_gym.common.validation import whole_number
from snac_gym.envs.core import resolve_reference, validate_q0
from snac_gym.kernels.compiled import POLICY_KERNEL_MODULES, warm_up
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.ur_models import UR_MODELS, get_ur_model, series_of, velocity_limits
from snac_gym.policies import make_policy
from snac_gym.policies.base import PolicyContext
from snac_gym.real.connections import (
    SERIES_FREQUENCY,
    ConnectionFailure,
    DryRunConnection,
    SimulatedConnection,
    URRTDEConnection,
)
from snac_gym.real.env import RealUREnv
from snac_gym.real.journal import StepJournal
from snac_gym.real.loop_tuning import LoopTuning, frozen_gc, tuned_process
from snac_gym.real.recovery import RecoveryLimits
from snac_gym.real.safety import SafetyLayer, SafetyLimits
from snac_gym.rollout import add_critic_diagnostics, partial_log, rollout, write_log
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

#: The streamed log (:class:`~snac_gym.real.journal.StepJournal`): kept only when the run could not write the full one.
STREAM_SUFFIX = "stream.csv"

#: Signals that end a real run through the same stop path as Ctrl-C: every catchable one whose
#: default action ends the process (SIGPIPE aside: Python ignores it). SIGKILL cannot be caught:
#: then the client process dies with the run and the controller's watchdog
#: (:class:`~snac_gym.real.connections.URRTDEConnection`) stops the arm.
STOP_SIGNALS = (*COMMAND_STOP_SIGNALS, signal.SIGUSR1, signal.SIGUSR2)


def stop_signals_raise() -> AbstractContextManager[SignalGuard]:
    """Within the block, the first signal of :data:`STOP_SIGNALS` raises :class:`TerminationSignal`
    (:func:`snac_gym.common._signals.stop_signals_raise` with the real run's wider set)."""
    return _stop_signals_raise(STOP_SIGNALS)


@dataclass
class RealRunResult:
    """What :func:`run_real_episode` produced: the demo figures plus loop timing and stop reason."""

    demo: Any
    timing: dict[str, float]
    stop_reason: str | None
    sent_commands: int | None = None
    files: list[Path] = field(default_factory=list)
    recoveries: list[dict[str, Any]] = field(default_factory=list)
    tuning_notes: list[str] = field(default_factory=list)
    #: The checked start pose, reference and limits (:func:`run_setup`).
    setup: dict[str, Any] = field(default_factory=dict)
    #: Whether missed deadlines stopped the arm (:attr:`SafetyLimits.deadline_stop`); off in a rehearsal.
    deadline_stop: bool = True
    #: How the last stop ended on an arm (:func:`stop_record`): which source confirmed rest, or why none did.
    rest: dict[str, Any] = field(default_factory=dict)

    @property
    def exit_code(self) -> int:
        """``snac-gym real``'s exit code for this end: 0 the episode ran to its end, 4 the safety layer stopped
        the arm, 5 the controller reported a protective stop, 6 an emergency stop, 7 the arm was stopped but
        nothing confirmed it at rest (:data:`EXIT_CODES`; ``rest_not_confirmed`` in ``*_real.json`` says why)."""
        if self.rest.get("rest_confirmed") is False:
            return 7
        if not self.stop_reason:
            return 0
        for state, code in (("protective_stop", 5), ("emergency_stop", 6)):
            if self.stop_reason == f"controller reports {state}":
                return code
        return 4

    def summary(self) -> str:
        lines = [self.demo.summary()]
        if self.timing:
            t = self.timing
            lines.append(
                f"  loop period                 mean {t['period_ms_mean']:.3f} ms, p99 {t['period_ms_p99']:.3f} ms, "
                f"max jitter {t['jitter_ms_max']:.3f} ms, {t['late_periods']} late"
            )
        if self.timing:
            lines.append(
                f"  late periods                {late_periods(self.timing)}"
                + (
                    ""
                    if self.deadline_stop
                    else ": counted only, a rehearsal has no deadline stop (--deadline-stop for one)"
                )
            )
        if self.timing and self.timing.get("speed_scaling_min", 1.0) < 1.0:
            lines.append(
                f"  speed slider                at {self.timing['speed_scaling_min']:.0%} (lowest): the controller "
                "scaled every command down, the arm was slower by design, not lagging"
            )
        for k, r in enumerate(self.recoveries, 1):
            lines.append(
                f"  recovery {k}                  {r['kind']} before step {r['step']}, {r['cleared_by']}, "
                f"resumed after a {r['gap_s']:.2f} s gap"
            )
        lines += [f"  loop tuning                 {note}" for note in self.tuning_notes]
        if self.sent_commands is not None:
            lines.append(f"  dry run: {self.sent_commands} commands computed, none sent")
        lines.append(f"  stopped by safety layer: {self.stop_reason}" if self.stop_reason else "  no safety stop")
        if self.rest.get("rest_confirmed"):
            lines.append(
                f"  at rest                     confirmed after {self.rest['rest_confirmed_after_s']:.2f} s by "
                f"{self.rest['rest_confirmed_by']} ({self.rest['stopped_by']})"
            )
        elif self.rest.get("rest_confirmed") is False:
            lines.append(f"  NOT confirmed at rest: {self.rest['rest_not_confirmed']} ({self.rest['stopped_by']})")
        return "\n".join(lines)


def late_periods(timing: dict[str, float]) -> str:
    """``"N of M (worst X ms)"``: the late periods of a run's :meth:`~snac_gym.real.env.RealUREnv.timing`, with
    the stalled ones (over ``max_period``) when there were any."""
    stalled = timing.get("stalled_periods", 0)
    worst = f"worst {timing['period_ms_max']:.1f} ms" + (f", {stalled} stalled" if stalled else "")
    return f"{timing['late_periods']} of {timing['periods']} ({worst})"


def is_rehearsal(connection: str, dry_run: bool) -> bool:
    """Whether a run is a rehearsal: a simulated arm (``sim``) or a dry run, where nothing reaches an arm."""
    return connection == "sim" or dry_run


def resolve_deadline_stop(
    safety: SafetyLimits, connection: str, dry_run: bool, deadline_stop: bool | None
) -> SafetyLimits:
    """``safety`` with the run's deadline stop: ``deadline_stop`` if given, else on for a real (or emulated) arm
    and off for a rehearsal (:func:`is_rehearsal`: late periods are then only counted and reported).

    Raises:
        ValueError: If the deadline stop would be off for an arm that moves (``--connection rtde`` without
            ``--dry-run``): a late loop there is a hazard, not a statistic.
    """
    rehearsal = is_rehearsal(connection, dry_run)
    stop = (safety.deadline_stop and not rehearsal) if deadline_stop is None else bool(deadline_stop)
    if not stop and not rehearsal:
        raise ValueError(
            "--no-deadline-stop is for a rehearsal (--connection sim or --dry-run): "
            "on a real or emulated arm missed deadlines stop it"
        )
    return replace(safety, deadline_stop=stop)


#: ``snac-gym real``'s exit codes, by how the run ended (``--help`` and docs/real-arm.md list them).
EXIT_CODES = {
    "ran to its end (or a dry run)": 0,
    "link to the arm lost": 1,
    "input refused": 2,
    "unexpected error": 3,
    "safety layer stopped the arm": 4,
    "protective stop": 5,
    "emergency stop": 6,
    "stopped, but nothing confirmed the arm at rest": 7,
    "signal n": "128 + n",
}


def stop_record(connection: Any) -> dict[str, Any]:
    """How the connection's last stop ended (:meth:`~snac_gym.real.connections.URRTDEConnection.stop_record`):
    ``{}`` for a connection without one (simulated, dry run)."""
    record = getattr(connection, "stop_record", None)
    return {} if record is None else record()


#: Longest episode ``snac-gym real`` runs, s (``--steps`` is bounded by it at 500 Hz): an hour of streaming.
MAX_REAL_SECONDS = 3600.0
#: The arms ``snac-gym real`` drives: the UR models of the registry (ur_rtde; ``snac-gym emulate-ur`` serves the same).
UR_ROBOTS = tuple(UR_MODELS)


def run_setup(
    task: str, robot: str, q0: Sequence[float] | None, reference: Any, safety: SafetyLimits, series: str | None = None
) -> dict[str, Any]:
    """The checked start pose, reference and limits of a real run, before anything connects; ``*_real.json``
    records it and the dry run prints it.

    ``q0`` and ``reference`` (the task's reset-option value, e.g. the target ``[x, y, z]`` of reach) default to
    the paper's (``snac-gym demo``'s), which the UR10 reaches; the smaller arms need their own.

    Raises:
        ValueError: Naming what is wrong: a robot that is not a UR arm, a series it does not run at, a start pose
            outside the joint limits or the safety margins, an unreachable reference or one beyond the
            datasheet's reach (from the shoulder), or a start or reference outside the task box.
    """
    if robot not in UR_ROBOTS:
        raise ValueError(f"--robot must be one of {', '.join(UR_ROBOTS)} (the UR arms ur_rtde drives), got {robot!r}")
    series = series_of(robot, series)
    spec, kinematics = get_task(task), Kinematics(robot)
    options = spec.demo_options()
    if q0 is not None:
        options["q0"] = [float(v) for v in q0]
    if reference is not None:
        options[spec.option_key] = reference
    hint = (
        ""
        if robot == "ur10" or (q0 is not None and reference is not None)
        else (f" (the paper's start pose and reference are the UR10's: give --q0 and the reference for {robot})")
    )
    try:
        start = validate_q0(kinematics, options["q0"])
        resolved = resolve_reference(
            spec, kinematics, np.random.default_rng(0), SampleSpace.for_robot(kinematics), options
        )
    except ValueError as exc:
        raise ValueError(re.sub(r"options\['(\w+)'\]", r"--\1", str(exc)) + hint) from None
    layer = SafetyLayer(kinematics, safety, 1.0)
    violation = layer.pose_violation(start, kinematics.forward(start))
    if violation is not None:
        raise ValueError(f"--q0 is outside the safety limits: {violation}{hint}")
    points = np.atleast_2d(resolved.points(64))
    model = get_ur_model(robot)
    shoulder = np.array([0.0, 0.0, model.dh[0]])
    distances = np.linalg.norm(points - shoulder, axis=1)
    farthest = int(np.argmax(distances))
    if distances[farthest] > model.reach:
        raise ValueError(
            f"the {task} reference reaches [{_fmt(points[farthest])}] m, {distances[farthest]:.3f} m from "
            f"the shoulder: beyond the {model.label}'s datasheet reach of {model.reach:.3f} m{hint}"
        )
    low, high = safety.task_box(kinematics)
    outside = [p for p in points if np.any(p < low) or np.any(p > high)]
    if outside:
        raise ValueError(
            f"the {task} reference leaves the task box [{_fmt(low)}] .. [{_fmt(high)}] m at "
            f"[{_fmt(outside[0])}]: choose another reference, or --task-box{hint}"
        )
    return {
        "robot": robot,
        "task": task,
        "q0": [float(v) for v in start],
        spec.option_key: options[spec.option_key],
        "task_box": [low.tolist(), high.tolist()],
        "joint_limit_margin": safety.joint_limit_margin,
        "speed_scale": safety.speed_scale,
        "max_joint_acceleration": safety.max_joint_acceleration,
        "series": series,
        "speed_limits": [float(v) for v in velocity_limits(robot, kinematics.velocity_limits)],
        "speed_limits_source": f"the URDF's, capped at the {model.source['speeds']}",
        "reach": model.reach,
        "deadline_stop": safety.deadline_stop,
    }


def _fmt(values: Any) -> str:
    return ", ".join(f"{v:.3f}" for v in np.asarray(values, dtype=float))


def make_connection(
    connection: str,
    host: str | None,
    series: str,
    dry_run: bool,
    robot: str = "ur10",
    echo: Callable[[str], None] | None = None,
    acceleration: float = 4.0,
) -> Any:
    """Build the ``rtde`` or ``sim`` connection (wrapped for a dry run).

    ``acceleration`` is ``speedJ``'s ramp (rad/s²) on a real arm: above the safety layer's bound,
    so that the arm follows the shaped command instead of trailing it.

    Raises:
        ValueError: On an unknown connection or a missing host.
        ConnectionFailure: If the arm cannot be reached.
    """
    if series not in SERIES_FREQUENCY:
        raise ValueError(f"series must be one of {sorted(SERIES_FREQUENCY)}, got {series!r}")
    kinematics = Kinematics(robot)
    if connection == "sim":
        inner: Any = SimulatedConnection(kinematics, frequency=SERIES_FREQUENCY[series], realtime=True)
    elif connection == "rtde":
        if not host:
            raise ValueError("the rtde connection needs --host IP (or use --connection sim to rehearse)")
        inner = URRTDEConnection(host, kinematics, series=series, control=not dry_run, acceleration=acceleration)
    else:
        raise ValueError(f"connection must be 'rtde' or 'sim', got {connection!r}")
    return DryRunConnection(inner, echo=echo) if dry_run else inner


def run_real_episode(
    task: str = "reach",
    controller: str = "snac",
    out_dir: str | Path | None = "real_out",
    connection: str = "rtde",
    host: str | None = None,
    series: str | None = None,
    dry_run: bool = False,
    seed: int = 0,
    steps: int | None = None,
    safety: SafetyLimits | None = None,
    policy_kwargs: dict[str, Any] | None = None,
    csv: bool = False,
    plots: bool = True,
    echo: Callable[[str], None] | None = None,
    model_error: str | None = None,
    recovery: RecoveryLimits | None = None,
    tuning: LoopTuning | None = None,
    journal_writer: str = "process",
    robot: str = "ur10",
    q0: Sequence[float] | None = None,
    reference: Any = None,
    deadline_stop: bool | None = None,
) -> RealRunResult:
    """Run the paper's ``task`` (same start pose and reference as ``snac-gym demo``) on an arm.

    The arm first moves to θ0 (``moveJ``), then the controller streams joint velocities through
    the safety layer. The arm is stopped whatever happens (``finally: env.close()``). Every way
    the episode can fail writes the rows logged so far, the loop timing and the reason to
    ``out_dir`` (``*_log.parquet``, ``*_timing.csv``, ``*_real.json`` with ``ended``: ``interrupted``,
    ``link lost`` or ``error``) before the exception propagates, with ``exc.log_dir`` set:

    * a signal of :data:`STOP_SIGNALS` raises :class:`TerminationSignal` (a ``KeyboardInterrupt``);
    * a lost link, or a ur_rtde client that blocked, crashed or began to reconnect and was killed,
      raises :class:`~snac_gym.real.connections.ConnectionFailure` (also when the episode had
      already ended in a safety stop: the controller's watchdog, not the host, stopped the arm);
    * any other exception (its traceback goes to ``*_real.json``).

    Meanwhile every period's row goes to ``*_stream.csv`` through the log's writer process
    (:class:`~snac_gym.real.journal.StepJournal`), which writes every row it got even when the
    host process is killed outright (SIGKILL); it is removed once the full log is written.

    Args:
        task: ``"reach"`` or ``"track"``.
        controller: Registered policy name.
        out_dir: Folder for the log, figures, timing and summary (``None``: write nothing).
        connection: ``"rtde"`` (a real arm at ``host``) or ``"sim"`` (PyBullet in wall-clock time).
        host: IP of the UR controller (``rtde`` only).
        series: ``"cb"`` (125 Hz) or ``"e"`` (500 Hz); ``None``: the arm's own
        (:func:`~snac_gym.model.ur_models.series_of`).
        dry_run: Connect and read state, send nothing; ``echo`` gets each command it would send.
        seed: Seed of the policy (and env) reset.
        steps: Control periods (default: the task's ``real_horizon_s``, 15 s reach, 30 s track).
        safety: Safety limits (default conservative :class:`SafetyLimits`).
        policy_kwargs: Constructor arguments of the policy.
        csv, plots: As for ``snac-gym demo``.
        echo: Where dry-run lines go (e.g. ``print``).
        model_error: Rehearse the controller with a wrong arm model (:mod:`snac_gym.model.model_error`),
            ``connection="sim"`` only: on a real arm the model's error is the arm's own.
        recovery: Whether the episode resumes after a protective stop or a lost link
            (:class:`~snac_gym.real.recovery.RecoveryLimits`; default: never). Each resumption is
            in the summary, in ``*_real.json`` (``recoveries``) and in the log's ``resumed_after_s``
            column (the gap's length, s, on the first row after it; NaN elsewhere).
        tuning: Real-time scheduling, memory lock, garbage collector frozen
            (:class:`~snac_gym.real.loop_tuning.LoopTuning`; default: none). What could not be
            applied is in the summary (``tuning_notes``); the run goes on without it.
        journal_writer: How the stream log is written: ``"process"`` (off the loop) or
            ``"inline"`` (:class:`~snac_gym.real.journal.StepJournal`).
        robot: The UR arm (:data:`UR_ROBOTS`): its kinematics, limits and default task box.
        q0, reference: The start pose (rad) and the task's reference option (reach: the target, m); default
            the paper's (:func:`run_setup`, which checks them before anything connects).
        deadline_stop: Whether missed deadlines stop the arm (:func:`resolve_deadline_stop`; ``None``: on for
            ``rtde``, off for ``sim`` and a dry run, where late periods are counted and reported:
            :meth:`RealRunResult.summary`, ``*_real.json``'s ``late_periods`` and ``setup``, the log's attrs).

    Raises:
        ValueError: For ``model_error`` with another connection than ``"sim"``, a dry run that
            would unlock a protective stop, or the deadline stop turned off for a real arm.
    """
    if connection == "sim" and host is not None:
        raise ValueError("--host is for --connection rtde (a real arm); --connection sim rehearses on PyBullet here")
    if steps is not None:
        whole_number("--steps", steps, 1, round(MAX_REAL_SECONDS * SERIES_FREQUENCY["e"]))
    whole_number("--seed", seed, 0, 2**32 - 1)
    if model_error is not None and connection != "sim":
        raise ValueError(
            "--model-error rehearses a wrong arm model on --connection sim only; a real arm's model error is its own"
        )
    if dry_run and recovery is not None and recovery.unlock_protective_stop:
        raise ValueError("--unlock-protective-stop sends a command to the controller's dashboard: not in a dry run")
    safety = resolve_deadline_stop(safety if safety is not None else SafetyLimits(), connection, dry_run, deadline_stop)
    setup = run_setup(task, robot, q0, reference, safety, series)
    series = setup["series"]
    if echo is not None:
        echo("setup: " + json.dumps(setup))
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:  # before the arm is connected: a file, a pipe or an unwritable --out is refused here
        usable_out_folder(out)
    prefix = f"{task}_{controller}_"
    tuning = tuning if tuning is not None else LoopTuning()
    with stop_signals_raise() as guard, tuned_process(tuning) as notes:
        arm = make_connection(
            connection, host, series, dry_run, robot=robot, echo=echo, acceleration=2.0 * safety.max_joint_acceleration
        )
        try:
            default_steps = round(get_task(task).real_horizon_s / arm.dt)
            env = RealUREnv(
                task, arm, safety=safety, max_steps=steps if steps is not None else default_steps, recovery=recovery
            )
            if out is not None:
                env.journal = StepJournal(out / f"{prefix}{STREAM_SUFFIX}", env.kinematics.n_joints, journal_writer)
        except BaseException:
            arm.close()
            raise
        with frozen_gc(tuning.freeze_gc):
            log = _run_and_stop(env, controller, policy_kwargs, seed, guard, out, prefix, setup, model_error)
        guard.defer()  # the arm is stopped: a signal now waits until the outputs are written
        result = _write_outputs(
            env, log, task, controller, connection, dry_run, seed, out, prefix, csv, plots, policy_kwargs, setup
        )
        result.tuning_notes = list(notes)
    try:
        guard.raise_pending()
    except TerminationSignal as exc:  # it came after the episode: the outputs are written all the same
        exc.log_dir = out  # type: ignore[attr-defined]
        raise
    return result


def _run_and_stop(
    env: RealUREnv,
    controller: str,
    policy_kwargs: dict[str, Any] | None,
    seed: int,
    guard: SignalGuard,
    out: Path | None,
    prefix: str,
    setup: dict[str, Any],
    model_error: str | None = None,
) -> pd.DataFrame:
    """The episode, the arm stopped on every way out; on any failure the log so far is written, then it raises.

    A client the connection had to give up (killed after a missed deadline, crashed, its link lost)
    fails the run even when the episode itself ended in a safety stop: the arm was then stopped
    by the controller's watchdog, not by the host.
    """
    log = None
    try:
        try:
            warm_up(POLICY_KERNEL_MODULES)  # compiled or loaded now, not in the first control period
            policy = make_policy(controller, PolicyContext.for_controller(env, model_error), **(policy_kwargs or {}))
            options = {"q0": setup["q0"], env.task.option_key: setup[env.task.option_key]}
            log = rollout(env, policy, options=options, seed=seed, steps=env.max_steps)
            log = add_critic_diagnostics(log, policy)
            _mark_gaps(log, env)
        finally:
            env.close()
        failure = getattr(env.connection, "failure", None)
        if failure is not None:
            after = f" (after the safety stop: {env.stop_reason})" if env.stop_reason else ""
            raise ConnectionFailure(failure + after)
    except BaseException as exc:
        guard.defer()
        if out is not None:
            _write_interrupted(env, partial_log(exc) if log is None else log, out, prefix, exc, setup)
            exc.log_dir = out  # type: ignore[attr-defined]
        raise
    finally:
        if env.journal is not None:
            env.journal.close()
    return log


def _mark_gaps(log: pd.DataFrame, env: RealUREnv) -> None:
    """The ``resumed_after_s`` column: each resumption's gap (s) on the first row after it (only when there was one)."""
    if not env.recoveries:
        return
    gaps = np.full(len(log), np.nan)
    for r in env.recoveries:
        if r["step"] < len(log):
            gaps[r["step"]] = r["gap_s"]
    log["resumed_after_s"] = gaps
    log.attrs["recoveries"] = [dict(r) for r in env.recoveries]


def _write_outputs(
    env: RealUREnv,
    log: pd.DataFrame,
    task: str,
    controller: str,
    connection: str,
    dry_run: bool,
    seed: int,
    out: Path | None,
    prefix: str,
    csv: bool,
    plots: bool,
    policy_kwargs: dict[str, Any] | None,
    setup: dict[str, Any],
) -> RealRunResult:
    log.attrs["controller"] = controller
    log.attrs["connection"] = connection + (" (dry run)" if dry_run else "")
    log.attrs["stop_reason"] = env.stop_reason
    log.attrs["deadline_stop"] = env.safety_limits.deadline_stop
    timing = env.timing()
    if timing:
        log.attrs["late_periods"] = late_periods(timing)
    limits = (env.kinematics.lower_limits, env.kinematics.upper_limits)
    demo = write_demo_outputs(
        log,
        task,
        controller,
        seed,
        env.success_tolerance,
        out,
        csv=csv,
        plots=plots,
        policy_kwargs=policy_kwargs,
        position_limits=limits,
    )
    arm = env.connection
    result = RealRunResult(
        demo=demo,
        timing=timing,
        stop_reason=env.stop_reason,
        sent_commands=len(arm.sent) if isinstance(arm, DryRunConnection) else None,
        recoveries=[dict(r) for r in env.recoveries],
        setup=setup,
        deadline_stop=env.safety_limits.deadline_stop,
        rest=stop_record(arm),
    )
    if out is not None:
        result.files = list(demo.files) + _write_timing(env, out, prefix, result, plots)
        (out / f"{prefix}{STREAM_SUFFIX}").unlink(missing_ok=True)  # the full log is written: the stream is a subset
    return result


def _ending(exc: BaseException) -> str:
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted"
    if isinstance(exc, ConnectionFailure):
        return "link lost"
    return "error"


def _write_interrupted(
    env: RealUREnv, log: pd.DataFrame | None, out: Path, prefix: str, exc: BaseException, setup: dict[str, Any]
) -> None:
    """Save what a failed run logged: the trajectory so far, the loop timing and why it ended.

    Each file is written on its own, so that one that fails (a full disk) does not cost the others.
    """
    out.mkdir(parents=True, exist_ok=True)
    if log is not None:
        log.attrs["stop_reason"] = env.stop_reason
        _attempt(lambda: write_log(log, out / f"{prefix}log.parquet"))
    periods = pd.DataFrame({"period_ms": np.asarray(env.periods) * 1e3})
    _attempt(lambda: write_whole(out / f"{prefix}timing.csv", lambda path: periods.to_csv(path, index_label="step")))
    connection = env.connection
    summary = {
        "ended": _ending(exc),
        "reason": f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__,
        "interrupted": type(exc).__name__,
        "signal": getattr(exc, "signal_name", None),
        "stop_reason": env.stop_reason,
        "client_failure": getattr(connection, "failure", None),
        "last_stop": getattr(connection, "last_stop", None),
        **stop_record(connection),
        "client_output": getattr(connection, "client_output", []),
        "steps_logged": 0 if log is None else len(log),
        "timing": env.timing(),
        **({"late_periods": late_periods(env.timing())} if env.periods else {}),
        "dt_ms": env.dt * 1e3,
        "setup": setup,
    }
    if env.recovery.max_recoveries:  # only a run that could resume says how it went
        summary["recoveries"] = env.recoveries
        summary["lost_links"] = getattr(connection, "lost_links", [])
    if _ending(exc) == "error":  # a bug: the CLI shows one line, the traceback is kept here
        summary["traceback"] = traceback.format_exception(exc)
    write_text_whole(out / f"{prefix}real.json", json.dumps(summary, indent=2, default=str))


def _attempt(write: Callable[[], object]) -> None:
    try:
        write()
    except Exception as exc:  # noqa: BLE001 - the other files are still written; the failure is shown
        print(f"warning: could not write part of the log: {type(exc).__name__}: {exc}", file=sys.stderr)


def _write_timing(env: RealUREnv, out: Path, prefix: str, result: RealRunResult, plots: bool) -> list[Path]:
    periods = pd.DataFrame({"period_ms": np.asarray(env.periods) * 1e3})
    timing_csv = out / f"{prefix}timing.csv"
    write_whole(timing_csv, lambda path: periods.to_csv(path, index_label="step"))
    summary = out / f"{prefix}real.json"
    write_text_whole(
        summary,
        json.dumps(
            {
                "timing": result.timing,
                **({"late_periods": late_periods(result.timing)} if result.timing else {}),
                "stop_reason": result.stop_reason,
                "dt_ms": env.dt * 1e3,
                "sent_commands": result.sent_commands,
                # What the last stop command returned (``None``: none was sent, e.g. a dry run).
                "last_stop": getattr(env.connection, "last_stop", None),
                # Which source confirmed the arm at rest after the last stop, and when (or why none did).
                **result.rest,
                "setup": result.setup,
                **({"recoveries": result.recoveries} if result.recoveries else {}),
            },
            indent=2,
        ),
    )
    files = [timing_csv, summary]
    if plots and len(periods):
        from snac_gym.apps.plots import plot_loop_timing, save_figure  # matplotlib only when plotting

        files.append(
            save_figure(plot_loop_timing(periods["period_ms"].to_numpy(), env.dt), out / f"{prefix}timing.png")
        )
    return files
