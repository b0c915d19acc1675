"""What a ``snac-gym real`` run leaves: its result (summary, exit code) and its files, whole after an episode and
partial after a failure.

Part of :mod:`snac_gym.apps.real`, which runs the episode and hands its log here.
"""

from __future__ import annotations

import json
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from snac_gym.apps.demo import write_demo_outputs
from snac_gym.apps.figures import demo_figures, draw_figures, timing_figure
from snac_gym.common._signals import SignalGuard
from snac_gym.common.outputs import write_text_whole, write_whole
from snac_gym.real.connections import (
    ConnectionFailure,
    DryRunConnection,
)
from snac_gym.real.env import RealUREnv
from snac_gym.rollout import write_log

__all__ = [
    "EXIT_CODES",
    "STREAM_SUFFIX",
    "RealRunResult",
    "late_periods",
    "mark_gaps",
    "stop_record",
    "write_interrupted",
    "write_outputs",
]

#: The streamed log (:class:`~snac_gym.real.journal.StepJournal`): kept only when the run could not write the full one.
STREAM_SUFFIX = "stream.csv"


@dataclass
class RealRunResult:
    """What :func:`~snac_gym.apps.real.run_real_episode` produced: the demo figures plus loop timing and stop reason."""

    demo: Any
    timing: dict[str, float]
    stop_reason: str | None
    sent_commands: int | None = None
    files: list[Path] = field(default_factory=list)
    recoveries: list[dict[str, Any]] = field(default_factory=list)
    tuning_notes: list[str] = field(default_factory=list)
    #: The checked start pose, reference and limits (:func:`~snac_gym.apps.real_setup.run_setup`).
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


def mark_gaps(log: pd.DataFrame, env: RealUREnv) -> None:
    """The ``resumed_after_s`` column: each resumption's gap (s) on the first row after it (only when there was one)."""
    if not env.recoveries:
        return
    gaps = np.full(len(log), np.nan)
    for r in env.recoveries:
        if r["step"] < len(log):
            gaps[r["step"]] = r["gap_s"]
    log["resumed_after_s"] = gaps
    log.attrs["recoveries"] = [dict(r) for r in env.recoveries]


def write_outputs(
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
    guard: SignalGuard | None = None,
    say: Callable[[str], object] | None = None,
) -> RealRunResult:
    """The run's log, summary, loop timing and ``*_real.json``, then its figures; ``guard`` (the run's, deferred since
    the arm stopped) lets a signal cut the figures, the rest being whole (``exc.kept`` says so); ``say`` hears how
    many figures are drawn where, before the first."""
    log.attrs["controller"] = controller
    log.attrs["connection"] = connection + (" (dry run)" if dry_run else "")
    log.attrs["stop_reason"] = env.stop_reason
    log.attrs["deadline_stop"] = env.safety_limits.deadline_stop
    timing = env.timing()
    if timing:
        log.attrs["late_periods"] = late_periods(timing)
    limits = (env.kinematics.lower_limits, env.kinematics.upper_limits)
    # The data first, figures last: a signal while the data is written waits for it (the guard defers it), one
    # while the figures are drawn stops the drawing (``resume``), so that a Ctrl-C after the episode is obeyed in
    # a second, not after all the figures (several seconds on a busy host), and costs no data.
    demo = write_demo_outputs(
        log,
        task,
        controller,
        seed,
        env.success_tolerance,
        out,
        csv=csv,
        plots=False,
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
        result.files = demo.files  # one list: the demo's "wrote N files" counts all the run wrote, timing and figures
        result.files += _write_timing(env, out, prefix, result)
        (out / f"{prefix}{STREAM_SUFFIX}").unlink(missing_ok=True)  # the full log is written: the stream is a subset
        if plots:
            drawers = {
                **demo_figures(log, env.success_tolerance),
                **timing_figure(np.asarray(env.periods) * 1e3, env.dt),
            }
            try:
                result.files += draw_figures(
                    drawers, out, prefix, before=None if guard is None else guard.resume, say=say
                )
            finally:  # deferred again: a signal after the figures must not cut the restoring of the process's tuning
                if guard is not None:
                    guard.defer()
    return result


def _ending(exc: BaseException) -> str:
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted"
    if isinstance(exc, ConnectionFailure):
        return "link lost"
    return "error"


def write_interrupted(
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


def _write_timing(env: RealUREnv, out: Path, prefix: str, result: RealRunResult) -> list[Path]:
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
    return [timing_csv, summary]
