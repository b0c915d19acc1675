"""One episode on a real UR arm (or its rehearsal): what ``snac-gym real`` does, importable.

The run's parts, each importable from here: :mod:`~snac_gym.apps.real_setup` (the checks before anything connects)
and :mod:`~snac_gym.apps.real_outputs` (the result and the files). :func:`run_real_episode` calls
:func:`make_connection` through this module, where tests replace it.
"""

from __future__ import annotations

import json
import signal
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

import pandas as pd

from snac_gym.apps.real_outputs import (
    EXIT_CODES,
    STREAM_SUFFIX,
    RealRunResult,
    late_periods,
    mark_gaps,
    stop_record,
    write_interrupted,
    write_outputs,
)
from snac_gym.apps.real_setup import MAX_REAL_SECONDS, UR_ROBOTS, is_rehearsal, resolve_deadline_stop, run_setup
from snac_gym.common._signals import STOP_SIGNALS as COMMAND_STOP_SIGNALS
from snac_gym.common._signals import SignalGuard, TerminationSignal
from snac_gym.common._signals import stop_signals_raise as _stop_signals_raise
from snac_gym.common.outputs import removed_if_left_empty
from snac_gym.common.progress import compiling_line
from snac_gym.common.validation import whole_number
from snac_gym.kernels.compiled import POLICY_KERNEL_MODULES, on_first_compile, warm_up
from snac_gym.model.kinematics import Kinematics, shared_kinematics
from snac_gym.policies import make_policy
from snac_gym.policies.base import PolicyContext
from snac_gym.real.connections import (
    SERIES_FREQUENCY,
    ArmConnection,
    ConnectionFailure,
    DryRunConnection,
    SimulatedConnection,
    URRTDEConnection,
)
from snac_gym.real.env import RealUREnv
from snac_gym.real.journal import StepJournal
from snac_gym.real.loop_tuning import LoopTuning, frozen_gc, tuned_process
from snac_gym.real.recovery import RecoveryLimits
from snac_gym.real.safety import SafetyLimits
from snac_gym.rollout import add_critic_diagnostics, partial_log, rollout
from snac_gym.tasks import get_task

__all__ = [
    "EXIT_CODES",
    "MAX_REAL_SECONDS",
    "STOP_SIGNALS",
    "STREAM_SUFFIX",
    "UR_ROBOTS",
    "RealRunResult",
    "TerminationSignal",
    "is_rehearsal",
    "late_periods",
    "make_connection",
    "resolve_deadline_stop",
    "run_real_episode",
    "run_setup",
    "stop_record",
    "stop_signals_raise",
]

#: What a run says (``progress``) as its first kernel compiles: the first run after an install waits seconds before
#: its control loop starts, with nothing else to say.
COMPILING = compiling_line("real", "before the control loop starts")
#: Signals that end a real run through the same stop path as Ctrl-C: every catchable one whose
#: default action ends the process (SIGPIPE aside: Python ignores it). SIGKILL cannot be caught:
#: then the client process dies with the run and the controller's watchdog
#: (:class:`~snac_gym.real.connections.URRTDEConnection`) stops the arm.
STOP_SIGNALS = (*COMMAND_STOP_SIGNALS, signal.SIGUSR1, signal.SIGUSR2)


def stop_signals_raise() -> AbstractContextManager[SignalGuard]:
    """Within the block, the first signal of :data:`STOP_SIGNALS` raises :class:`TerminationSignal`
    (:func:`snac_gym.common._signals.stop_signals_raise` with the real run's wider set)."""
    return _stop_signals_raise(STOP_SIGNALS)


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
    _check_connection(connection)
    if series not in SERIES_FREQUENCY:
        raise ValueError(f"series must be one of {sorted(SERIES_FREQUENCY)}, got {series!r}")
    kinematics = Kinematics(robot)
    if connection == "sim":
        inner: Any = SimulatedConnection(kinematics, frequency=SERIES_FREQUENCY[series], realtime=True)
    else:
        if not host:
            raise ValueError("the rtde connection needs --host IP (or use --connection sim to rehearse)")
        inner = URRTDEConnection(host, kinematics, series=series, control=not dry_run, acceleration=acceleration)
    return DryRunConnection(inner, echo=echo) if dry_run else inner


def _check_connection(connection: str) -> None:
    """Refuse a connection other than ``"rtde"`` and ``"sim"``."""
    if connection not in ("rtde", "sim"):
        raise ValueError(f"connection must be 'rtde' or 'sim', got {connection!r}")


def _check_inputs(
    connection: str,
    host: str | None,
    steps: int | None,
    seed: int,
    model_error: str | None,
    robot: str,
    dry_run: bool,
    recovery: RecoveryLimits | None,
) -> None:
    """Refuse what :func:`run_real_episode` cannot run, before its output folder is made or anything connects."""
    if connection == "sim" and host is not None:
        raise ValueError("--host is for --connection rtde (a real arm); --connection sim rehearses on PyBullet here")
    if steps is not None:
        whole_number("--steps", steps, 1, round(MAX_REAL_SECONDS * SERIES_FREQUENCY["e"]))
    whole_number("--seed", seed, 0, 2**32 - 1)
    _check_connection(connection)  # here too, not only where it connects: before --out is made
    if model_error is not None and connection != "sim":
        raise ValueError(
            "--model-error rehearses a wrong arm model on --connection sim only; a real arm's model error is its own"
        )
    if model_error is not None:  # built once here, so that a malformed error is refused before --out is made
        shared_kinematics(robot).with_model_error(model_error)
    if dry_run and recovery is not None and recovery.unlock_protective_stop:
        raise ValueError("--unlock-protective-stop sends a command to the controller's dashboard: not in a dry run")


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
    progress: Callable[[str], object] | None = None,
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

    Once the episode has ended, a signal waits while its log, summary, loop timing and ``*_real.json`` are written,
    then stops the figures (each drawn whole or not at all) and raises, ``exc.kept`` saying how many were drawn.

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
        progress: Hears a line (no newline) for a command's stderr: :data:`COMPILING` where a kernel compiles before
            the loop, when the loop starts, and the figures drawn.

    Raises:
        ValueError: For ``model_error`` with another connection than ``"sim"``, a dry run that
            would unlock a protective stop, or the deadline stop turned off for a real arm.
    """
    _check_inputs(connection, host, steps, seed, model_error, robot, dry_run, recovery)
    safety = resolve_deadline_stop(safety if safety is not None else SafetyLimits(), connection, dry_run, deadline_stop)
    setup = run_setup(task, robot, q0, reference, safety, series)
    series = setup["series"]
    if echo is not None:
        echo("setup: " + json.dumps(setup))
    out = Path(out_dir) if out_dir is not None else None
    prefix = f"{task}_{controller}_"
    tuning = tuning if tuning is not None else LoopTuning()
    # The folder made before the arm is connected (a file, a pipe or an unwritable --out is refused here), and removed
    # again if the run ends before it wrote anything there (a controller that does not answer).
    with removed_if_left_empty(out), stop_signals_raise() as guard, tuned_process(tuning) as notes:

        def connect() -> ArmConnection:
            return make_connection(
                connection, host, series, dry_run, robot=robot, echo=echo,
                acceleration=2.0 * safety.max_joint_acceleration,
            )  # fmt: skip

        def make_env(arm: ArmConnection) -> RealUREnv:
            default_steps = round(get_task(task).real_horizon_s / arm.dt)
            return RealUREnv(
                task, arm, safety=safety, max_steps=steps if steps is not None else default_steps, recovery=recovery
            )

        stream = None if out is None else out / f"{prefix}{STREAM_SUFFIX}"
        env, log = _run_and_stop(
            connect, make_env, controller, policy_kwargs, seed, guard, out, prefix, setup, model_error, tuning,
            stream, journal_writer, progress,
        )  # fmt: skip
        try:
            result = write_outputs(
                env, log, task, controller, connection, dry_run, seed, out, prefix, csv, plots, policy_kwargs, setup,
                guard, say=None if progress is None else (lambda text: progress(f"real: {text}")),
            )  # fmt: skip
            result.tuning_notes = list(notes)
            guard.raise_pending()
        except TerminationSignal as exc:  # it came after the episode: the data is written, some figures may not be
            exc.log_dir = out  # type: ignore[attr-defined]
            raise
    return result


def _run_and_stop(
    connect: Callable[[], ArmConnection],
    make_env: Callable[[ArmConnection], RealUREnv],
    controller: str,
    policy_kwargs: dict[str, Any] | None,
    seed: int,
    guard: SignalGuard,
    out: Path | None,
    prefix: str,
    setup: dict[str, Any],
    model_error: str | None,
    tuning: LoopTuning,
    stream: Path | None,
    journal_writer: str,
    progress: Callable[[str], object] | None = None,
) -> tuple[RealUREnv, pd.DataFrame]:
    """The episode, the arm stopped on every way out; on any failure the log so far is written, then it raises.

    The arm is connected, the env built and the stream log opened in here, so that no signal can come between an
    open connection and the handler that stops the arm, or between a file written and the handler that writes the
    rest and says where: a signal before the env exists leaves nothing written.

    A client the connection had to give up (killed after a missed deadline, crashed, its link lost)
    fails the run even when the episode itself ended in a safety stop: the arm was then stopped
    by the controller's watchdog, not by the host.
    """
    arm = connect()
    try:
        env = make_env(arm)
    except BaseException:
        arm.close()
        raise
    log = None
    try:
        try:
            if stream is not None:
                env.journal = StepJournal(stream, env.kinematics.n_joints, journal_writer)
            with frozen_gc(tuning.freeze_gc):
                with on_first_compile(lambda: progress(COMPILING)) if progress is not None else nullcontext():
                    warm_up(POLICY_KERNEL_MODULES)  # compiled or loaded now, not in the first control period
                policy = make_policy(
                    controller, PolicyContext.for_controller(env, model_error), **(policy_kwargs or {})
                )
                options = {"q0": setup["q0"], env.task.option_key: setup[env.task.option_key]}
                if progress is not None:  # the arm moves from here on: a reader should know when
                    progress(f"real: the control loop starts: {env.max_steps} periods of {env.dt * 1e3:g} ms "
                             f"({env.max_steps * env.dt:g} s)")  # fmt: skip
                log = rollout(env, policy, options=options, seed=seed, steps=env.max_steps)
                log = add_critic_diagnostics(log, policy)
                mark_gaps(log, env)
        finally:
            env.close()
        failure = getattr(env.connection, "failure", None)
        if failure is not None:
            after = f" (after the safety stop: {env.stop_reason})" if env.stop_reason else ""
            raise ConnectionFailure(failure + after)
    except BaseException as exc:
        guard.defer()
        if out is not None:
            write_interrupted(env, partial_log(exc) if log is None else log, out, prefix, exc, setup)
            exc.log_dir = out  # type: ignore[attr-defined]
        raise
    else:  # the arm is stopped: a signal now waits until the data is written (write_outputs lets it cut the figures)
        guard.defer()
    finally:
        if env.journal is not None:
            env.journal.close()  # waits for the writer process: a signal meanwhile must not cost the log
    return env, log
