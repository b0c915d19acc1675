"""One episode on a real UR arm (or its rehearsal): what ``snac-gym real`` does, importable."""

from __future__ import annotations

import json
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from snac_gym.kinematics import Kinematics
from snac_gym.real.backends import SERIES_FREQUENCY, DryRunBackend, SimulatedBackend, URRTDEBackend
from snac_gym.real.env import RealUREnv
from snac_gym.real.safety import SafetyLimits
from snac_gym.tasks import get_task

#: Signals that end a real run through the same stop path as Ctrl-C. SIGKILL cannot be caught:
#: then the controller's watchdog (:class:`~snac_gym.real.backends.URRTDEBackend`) stops the arm.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class TerminationSignal(KeyboardInterrupt):
    """A stop signal (SIGINT, SIGTERM, SIGHUP) received during a real run.

    A ``KeyboardInterrupt``, so that everything that stops the arm and saves the log on Ctrl-C
    does the same for the others.
    """

    def __init__(self, signum: int) -> None:
        self.signum = int(signum)
        self.signal_name = signal.Signals(signum).name
        super().__init__(self.signal_name)


@contextmanager
def stop_signals_raise() -> Iterator[None]:
    """Within the block, every signal of :data:`STOP_SIGNALS` raises :class:`TerminationSignal`.

    SIGINT is included because a run started from a background shell inherits it ignored.
    Handlers can only be set from the main thread; elsewhere the block runs unchanged.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def raise_termination(signum: int, _frame: Any) -> None:
        raise TerminationSignal(signum)

    previous = {signum: signal.signal(signum, raise_termination) for signum in STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


@dataclass
class RealRunResult:
    """What :func:`run_real_episode` produced: the demo figures plus loop timing and stop reason."""

    demo: Any
    timing: dict[str, float]
    stop_reason: str | None
    sent_commands: int | None = None
    files: list[Path] = field(default_factory=list)

    def summary(self) -> str:
        lines = [self.demo.summary()]
        if self.timing:
            t = self.timing
            lines.append(
                f"  loop period                 mean {t['period_ms_mean']:.3f} ms, p99 {t['period_ms_p99']:.3f} ms, "
                f"max jitter {t['jitter_ms_max']:.3f} ms, {t['late_periods']} late"
            )
        if self.timing and self.timing.get("speed_scaling_min", 1.0) < 1.0:
            lines.append(
                f"  speed slider                at {self.timing['speed_scaling_min']:.0%} (lowest): the controller "
                "scaled every command down, the arm was slower by design, not lagging"
            )
        if self.sent_commands is not None:
            lines.append(f"  dry run: {self.sent_commands} commands computed, none sent")
        lines.append(f"  stopped by safety layer: {self.stop_reason}" if self.stop_reason else "  no safety stop")
        return "\n".join(lines)


def make_backend(
    backend: str,
    host: str | None,
    series: str,
    dry_run: bool,
    robot: str = "ur10",
    echo: Callable[[str], None] | None = None,
    acceleration: float = 4.0,
) -> Any:
    """Build the ``rtde`` or ``sim`` backend (wrapped for a dry run).

    ``acceleration`` is ``speedJ``'s ramp (rad/s²) on a real arm: above the safety layer's bound,
    so that the arm follows the shaped command instead of trailing it.

    Raises:
        ValueError: On an unknown backend or a missing host.
        ConnectionFailure: If the arm cannot be reached.
    """
    if series not in SERIES_FREQUENCY:
        raise ValueError(f"series must be one of {sorted(SERIES_FREQUENCY)}, got {series!r}")
    kinematics = Kinematics(robot)
    if backend == "sim":
        inner: Any = SimulatedBackend(kinematics, frequency=SERIES_FREQUENCY[series], realtime=True)
    elif backend == "rtde":
        if not host:
            raise ValueError("the rtde backend needs --host IP (or use --backend sim to rehearse)")
        inner = URRTDEBackend(host, kinematics, series=series, control=not dry_run, acceleration=acceleration)
    else:
        raise ValueError(f"backend must be 'rtde' or 'sim', got {backend!r}")
    return DryRunBackend(inner, echo=echo) if dry_run else inner


def run_real_episode(
    task: str = "reach",
    controller: str = "snac",
    out_dir: str | Path | None = "real_out",
    backend: str = "rtde",
    host: str | None = None,
    series: str = "cb",
    dry_run: bool = False,
    seed: int = 0,
    steps: int | None = None,
    safety: SafetyLimits | None = None,
    policy_kwargs: dict[str, Any] | None = None,
    csv: bool = False,
    plots: bool = True,
    echo: Callable[[str], None] | None = None,
) -> RealRunResult:
    """Run the paper's ``task`` (same start pose and reference as ``snac-gym demo``) on an arm.

    The arm first moves to θ0 (``moveJ``), then the controller streams joint velocities through
    the safety layer. The arm is stopped whatever happens (``finally: env.close()``). SIGINT,
    SIGTERM and SIGHUP raise :class:`TerminationSignal` (a ``KeyboardInterrupt``) in the loop: the
    arm is stopped, and the rows logged so far, the loop timing and the reason are written to
    ``out_dir`` (``*_log.parquet``, ``*_timing.csv``, ``*_real.json``) before it propagates; any
    other exception mid-episode saves them the same way.

    Args:
        task: ``"reach"`` or ``"track"``.
        controller: Registered policy name.
        out_dir: Folder for the log, figures, timing and summary (``None``: write nothing).
        backend: ``"rtde"`` (a real arm at ``host``) or ``"sim"`` (PyBullet in wall-clock time).
        host: IP of the UR controller (``rtde`` only).
        series: ``"cb"`` (125 Hz) or ``"e"`` (500 Hz).
        dry_run: Connect and read state, send nothing; ``echo`` gets each command it would send.
        seed: Seed of the policy (and env) reset.
        steps: Control periods (default: the task's ``real_horizon_s``, 15 s reach, 30 s track).
        safety: Safety limits (default conservative :class:`SafetyLimits`).
        policy_kwargs: Constructor arguments of the policy.
        csv, plots: As for ``snac-gym demo``.
        echo: Where dry-run lines go (e.g. ``print``).
    """
    from snac_gym.demo import write_demo_outputs
    from snac_gym.policies import make_policy
    from snac_gym.rollout import add_critic_diagnostics, partial_log, rollout

    safety = safety if safety is not None else SafetyLimits()
    arm = make_backend(backend, host, series, dry_run, echo=echo, acceleration=2.0 * safety.max_joint_acceleration)
    try:
        default_steps = round(get_task(task).real_horizon_s / arm.dt)
        env = RealUREnv(task, arm, safety=safety, max_steps=steps if steps is not None else default_steps)
    except BaseException:
        arm.close()
        raise
    try:
        with stop_signals_raise():
            try:
                policy = make_policy(controller, env, **(policy_kwargs or {}))
                log = add_critic_diagnostics(
                    rollout(env, policy, options=env.task.demo_options(), seed=seed, steps=env.max_steps), policy
                )
            finally:
                env.close()
    except BaseException as exc:
        partial = partial_log(exc)
        if partial is not None and out_dir is not None:
            _write_interrupted(env, partial, Path(out_dir), f"{task}_{controller}_", exc)
        raise
    log.attrs["controller"] = controller
    log.attrs["backend"] = backend + (" (dry run)" if dry_run else "")
    log.attrs["stop_reason"] = env.stop_reason
    demo = write_demo_outputs(
        log, task, controller, seed, env.success_tolerance, out_dir, csv=csv, plots=plots, policy_kwargs=policy_kwargs
    )
    result = RealRunResult(
        demo=demo,
        timing=env.timing(),
        stop_reason=env.stop_reason,
        sent_commands=len(arm.sent) if isinstance(arm, DryRunBackend) else None,
    )
    if out_dir is not None:
        result.files = list(demo.files) + _write_timing(env, Path(out_dir), f"{task}_{controller}_", result, plots)
    return result


def _write_interrupted(env: RealUREnv, log: pd.DataFrame, out: Path, prefix: str, exc: BaseException) -> None:
    """Save what an interrupted run logged: the trajectory so far, the loop timing and why it ended."""
    from snac_gym.rollout import write_log

    out.mkdir(parents=True, exist_ok=True)
    log.attrs["stop_reason"] = env.stop_reason
    write_log(log, out / f"{prefix}log.parquet")
    pd.DataFrame({"period_ms": np.asarray(env.periods) * 1e3}).to_csv(out / f"{prefix}timing.csv", index_label="step")
    (out / f"{prefix}real.json").write_text(
        json.dumps(
            {
                "interrupted": type(exc).__name__,
                "signal": getattr(exc, "signal_name", None),
                "stop_reason": env.stop_reason,
                "steps_logged": len(log),
                "timing": env.timing(),
                "dt_ms": env.dt * 1e3,
            },
            indent=2,
        )
    )


def _write_timing(env: RealUREnv, out: Path, prefix: str, result: RealRunResult, plots: bool) -> list[Path]:
    periods = pd.DataFrame({"period_ms": np.asarray(env.periods) * 1e3})
    timing_csv = out / f"{prefix}timing.csv"
    periods.to_csv(timing_csv, index_label="step")
    summary = out / f"{prefix}real.json"
    summary.write_text(
        json.dumps(
            {
                "timing": result.timing,
                "stop_reason": result.stop_reason,
                "dt_ms": env.dt * 1e3,
                "sent_commands": result.sent_commands,
            },
            indent=2,
        )
    )
    files = [timing_csv, summary]
    if plots and len(periods):
        from snac_gym.plots import plot_loop_timing, save_figure

        files.append(
            save_figure(plot_loop_timing(periods["period_ms"].to_numpy(), env.dt), out / f"{prefix}timing.png")
        )
    return files
