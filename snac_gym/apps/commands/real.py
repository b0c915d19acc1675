"""The commands of a real UR arm: ``real`` (one episode behind the safety layer) and ``emulate-ur`` (a UR
controller for ur_rtde on this machine, with faults on demand)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Optional, cast

import typer

from snac_gym.apps.commands.common import (
    UR_ARMS,
    check_controller,
    check_task,
    check_ur_arm,
    interrupted,
    option_message,
    path_option,
    registered_tasks,
    renamed_option,
)
from snac_gym.common import startup
from snac_gym.common._signals import TerminationSignal
from snac_gym.tasks import get_task

__all__ = ["emulate_ur", "real"]


def real(
    host: Optional[str] = typer.Option(None, "--host", help="IP of the UR controller (--connection rtde)."),
    task: str = typer.Option(
        "reach", "--task", help=f"A registered task ({registered_tasks()}): the demo's start pose and reference."
    ),
    controller: str = typer.Option("snac", "--controller", help="Any registered policy name."),
    out: Path = path_option(
        Path("real_out"), "--out", "a folder", "Folder for the log, the panels and the loop timing."
    ),
    connection: str = typer.Option(
        "rtde", "--connection", help="rtde (a real arm at --host) or sim (rehearse on PyBullet in real time)."
    ),
    backend: Optional[str] = typer.Option(None, "--backend", hidden=True, help="Deprecated name of --connection."),
    series: Optional[str] = typer.Option(
        None, "--series", help="cb (CB3, 125 Hz) or e (e-Series, 500 Hz); default the arm's own."
    ),
    dry_run: bool = typer.Option(
        False, "--dry-run", help="Connect and read state, send nothing; print what would be sent."
    ),
    speed_scale: float = typer.Option(
        0.25, "--speed-scale", help="Fraction of the velocity limits allowed, in (0, 1]."
    ),
    max_acceleration: float = typer.Option(
        2.0, "--max-acceleration", help="Bound on joint acceleration, rad/s², in (0, 40]."
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of the policy reset."),
    steps: Optional[int] = typer.Option(
        None, "--steps", min=1, help="Control periods (default: 15 s reach, 30 s track)."
    ),
    csv: bool = typer.Option(False, "--csv", help="Also write the trajectory log as CSV."),
    plots: bool = typer.Option(True, "--plots/--no-plots", help="Write the PNG panels (after the arm is stopped)."),
    max_tcp_mismatch: float = typer.Option(
        0.005,
        "--max-tcp-mismatch",
        help="Largest distance (m) between the controller's TCP position and the model's f(q), in (0, 1].",
    ),
    model_error: Optional[str] = typer.Option(
        None, "--model-error", help="With --connection sim: give the controller a wrong arm model (as for evaluate)."
    ),
    max_recoveries: int = typer.Option(
        0,
        "--max-recoveries",
        min=0,
        max=100,
        help="Resume the episode after up to N protective stops or lost links (0: each ends the run).",
    ),
    unlock_protective_stop: bool = typer.Option(
        False,
        "--unlock-protective-stop",
        help="With --max-recoveries: unlock a protective stop from the dashboard after UR's 5 s lockout (else the "
        "operator clears it on the pendant).",
    ),
    recovery_timeout: float = typer.Option(
        60.0, "--recovery-timeout", help="Longest wait (s) for a protective stop to be cleared, in (0, 3600]."
    ),
    reconnect_timeout: float = typer.Option(
        10.0, "--reconnect-timeout", help="Longest time (s) for a lost link to come back, in (0, 600]."
    ),
    rt_priority: int = typer.Option(
        0,
        "--rt-priority",
        min=0,
        max=99,
        help="Real-time loop: SCHED_FIFO at this priority (the ur_rtde client too), memory locked, garbage "
        "collector frozen for the episode; 0: off.",
    ),
    robot: str = typer.Option(
        "ur10", "--robot", help=f"The UR arm: {UR_ARMS} (its kinematics, datasheet limits and default task box)."
    ),
    q0: Optional[str] = typer.Option(
        None,
        "--q0",
        help="Start pose, 6 joint angles in rad (comma-separated); default the paper's (the UR10's). The arm "
        "moveJs there first.",
    ),
    target: Optional[str] = typer.Option(
        None, "--target", help="Reach: the target x,y,z in m (base frame); default the paper's (the UR10's)."
    ),
    ellipse_centre: Optional[str] = typer.Option(
        None, "--ellipse-centre", help="Track: the ellipse's centre x,y,z in m; with --ellipse-radius."
    ),
    ellipse_radius: Optional[float] = typer.Option(
        None, "--ellipse-radius", help="Track: the circle's radius in m (the paper's plane and speed)."
    ),
    task_box: Optional[str] = typer.Option(
        None,
        "--task-box",
        help="The box the tool must stay in, x0,y0,z0,x1,y1,z1 in m; default the arm's sample cuboid grown by 0.15 m.",
    ),
    joint_margin: float = typer.Option(
        0.1, "--joint-margin", help="Distance (rad) from the joint limits that stops the arm, in [0, π/2]."
    ),
    deadline_stop: Optional[bool] = typer.Option(
        None,
        "--deadline-stop/--no-deadline-stop",
        help="Stop on missed deadlines (a late loop, a stall). Default: on for a real or emulated arm (always), "
        "off for --connection sim and --dry-run, where late periods are only counted and reported.",
    ),
) -> None:
    """Run one episode on a real UR arm (ur_rtde) behind the safety layer, or rehearse it with --connection sim.

    Exit codes: 0 the episode ran to its end; 1 the link to the arm was lost; 2 a refused input; 3 an
    unexpected error; 4 the safety layer stopped the arm; 5 the controller reported a protective stop;
    6 an emergency stop; 7 the arm was stopped but nothing confirmed it at rest (its real.json says why);
    128 + n a signal n (SIGINT 130, SIGTERM 143).
    """
    check_task(task)
    check_controller(controller)
    check_ur_arm(robot)
    # start-up time (apps.real: pandas, numba; after the checks: a usage error comes at once); tests swap SafetyLimits
    from snac_gym.apps.real import run_real_episode
    from snac_gym.real import ConnectionFailure, SafetyLimits
    from snac_gym.real.loop_tuning import LoopTuning
    from snac_gym.real.recovery import RecoveryLimits

    startup.imports_done()
    connection = renamed_option("--connection", connection, "--backend", backend, "rtde")
    try:
        try:
            recovery = RecoveryLimits(max_recoveries, unlock_protective_stop, recovery_timeout, reconnect_timeout)
        except ValueError as exc:  # the limits' own field names, told by their options'
            raise ValueError(option_message(str(exc), _REAL_OPTIONS)) from None
        box = None if task_box is None else _numbers("--task-box", task_box, 6)
        try:
            safety = SafetyLimits(
                speed_scale=speed_scale,
                max_joint_acceleration=max_acceleration,
                max_tcp_mismatch=max_tcp_mismatch,
                joint_limit_margin=joint_margin,
                box_low=None if box is None else cast("tuple[float, float, float]", tuple(box[:3])),  # 3 of 6
                box_high=None if box is None else cast("tuple[float, float, float]", tuple(box[3:])),
            )
        except ValueError as exc:  # the limits' own names, told by their options'
            field = next((name for name in _SAFETY_OPTIONS if str(exc).startswith(name)), None)
            raise ValueError(str(exc) if field is None else f"{_SAFETY_OPTIONS[field]} ({exc})") from None
        result = run_real_episode(
            task=task,
            controller=controller,
            out_dir=out,
            connection=connection,
            host=host,
            series=series,
            dry_run=dry_run,
            seed=seed,
            steps=steps,
            safety=safety,
            csv=csv,
            plots=plots,
            echo=typer.echo if dry_run else None,
            model_error=model_error,
            recovery=recovery,
            tuning=LoopTuning.realtime(rt_priority),
            robot=robot,
            q0=None if q0 is None else _numbers("--q0", q0, 6),
            reference=_real_reference(task, target, ellipse_centre, ellipse_radius),
            deadline_stop=deadline_stop,
            progress=lambda line: typer.echo(line, err=True),
        )
    except BaseException as exc:  # every way out: one line and a code of its own, never a traceback or a signal
        where = f"; the log so far is in {cast(Any, exc).log_dir}/" if getattr(exc, "log_dir", None) else ""
        line = str(exc).splitlines()[0] if str(exc) else ""
        if isinstance(exc, KeyboardInterrupt):  # Ctrl-C and the other stop signals: the arm was stopped
            # After the episode a signal cuts only the figures: ``kept`` says the data is whole, how many were drawn.
            kept = f"; {cast(Any, exc).kept}" if getattr(exc, "kept", None) else where
            raise interrupted(exc, f"the arm was stopped{kept or ' (before the episode: nothing logged)'}") from None
        if isinstance(exc, ConnectionFailure):  # the link or the ur_rtde client was lost: exit 1
            typer.echo(f"error: {line}{where}", err=True)
            raise typer.Exit(code=1) from None
        if isinstance(exc, (ValueError, RuntimeError)):
            typer.echo(
                f"error: {option_message(line, _REAL_OPTIONS) if isinstance(exc, ValueError) else line}{where}",
                err=True,
            )
            raise typer.Exit(code=2) from None
        if not isinstance(exc, Exception):
            raise
        typer.echo(f"error: unexpected {type(exc).__name__}: {line}{where} (traceback in its real.json)", err=True)
        raise typer.Exit(code=3) from None
    typer.echo(result.summary())
    if result.exit_code:  # the episode did not run to its end, or its arm is not known at rest: a script must see it
        raise typer.Exit(code=result.exit_code)


#: The options of ``real`` whose refusals name a field of :class:`~snac_gym.real.recovery.RecoveryLimits` or an
#: argument.
_REAL_OPTIONS = {
    "clear_timeout": "--recovery-timeout",
    "reconnect_timeout": "--reconnect-timeout",
    "connection": "--connection",
}
#: The options of ``real`` that set a field of :class:`~snac_gym.real.SafetyLimits`.
_SAFETY_OPTIONS = {
    "speed_scale": "--speed-scale",
    "max_joint_acceleration": "--max-acceleration",
    "joint_limit_margin": "--joint-margin",
    "max_tcp_mismatch": "--max-tcp-mismatch",
    "task box": "--task-box",
    "give both corners of the task box": "--task-box",
}


def _numbers(option: str, text: str, count: int) -> list[float]:
    """``count`` comma-separated finite numbers, or a ``ValueError`` naming ``option``."""
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        values = []
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{option} needs {count} finite numbers separated by commas, got {text!r}")
    return values


def _real_reference(task: str, target: str | None, centre: str | None, radius: float | None) -> Any:
    """The reference option of ``real``'s task from its options (``None``: the paper's): a fixed target or a circle,
    as the task's reference moves or not."""
    if not get_task(task).moving_reference:
        if centre is not None or radius is not None:
            raise ValueError("--ellipse-centre and --ellipse-radius are for --task track; reach takes --target")
        return None if target is None else _numbers("--target", target, 3)
    if target is not None:
        raise ValueError(f"--target is for --task reach; {task} takes --ellipse-centre and --ellipse-radius")
    if (centre is None) != (radius is None):
        raise ValueError("give --ellipse-centre and --ellipse-radius together")
    if centre is None:
        return None
    assert radius is not None  # given with centre (checked above)
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"--ellipse-radius must be a positive number of metres, got {radius!r}")
    return {"centre": _numbers("--ellipse-centre", centre, 3), "radius": float(radius)}


def emulate_ur(
    host: str = typer.Option(
        "127.0.0.1",
        "--host",
        help="Loopback address to listen on (127.x.x.x): one per emulator, as ur_rtde's ports are fixed.",
    ),
    port_base: int = typer.Option(
        29999, "--port-base", help="Dashboard port; RTDE at +5, script at +3/+4. ur_rtde needs 29999; 0: free ports."
    ),
    series: Optional[str] = typer.Option(
        None, "--series", help="cb (CB3, 125 Hz data) or e (e-Series, 500 Hz); default the arm's own."
    ),
    robot: str = typer.Option("ur10", "--robot", help=f"Arm model: {UR_ARMS} (the UR controller emulated)."),
    speed_scaling: float = typer.Option(1.0, "--speed-scaling", help="Speed slider fraction in (0, 1]."),
    tcp_offset: Optional[str] = typer.Option(
        None, "--tcp-offset", help="TCP offset x,y,z[,rx,ry,rz] (m, rad) in reported poses: a wrong tool."
    ),
    protective_stop_at: Optional[float] = typer.Option(
        None, "--protective-stop-at", help="Protective stop, s after the first speedJ."
    ),
    emergency_stop_at: Optional[float] = typer.Option(
        None, "--emergency-stop-at", help="Emergency stop, s after the first speedJ."
    ),
    latency_spike: Optional[str] = typer.Option(
        None, "--latency-spike", help="AT,SECONDS: the controller stalls that long, AT s after the first speedJ."
    ),
    drop_at: Optional[float] = typer.Option(
        None, "--drop-at", help="Cut every connection (and refuse new ones), s after the first speedJ."
    ),
    drop_for: Optional[float] = typer.Option(
        None, "--drop-for", help="With --drop-at: the link comes back after this many seconds (default: never)."
    ),
    stale_at: Optional[float] = typer.Option(
        None, "--stale-at", help="Freeze the reported timestamp and state, s after the first speedJ."
    ),
    watchdog_expiry_at: Optional[float] = typer.Option(
        None, "--watchdog-expiry-at", help="Make the RTDE watchdog fire, s after the first speedJ."
    ),
    nonfinite_at: Optional[float] = typer.Option(
        None, "--nonfinite-at", help="Report NaN joint angles (a corrupted package), s after the first speedJ."
    ),
    q0: Optional[str] = typer.Option(
        None,
        "--q0",
        help="The arm's pose at start, 6 joint angles in rad (comma-separated); default the nominal elbow-up pose.",
    ),
    duration: Optional[float] = typer.Option(
        None, "--duration", min=0.0, help="Exit after this many seconds (default: until Ctrl-C)."
    ),
    rt_priority: int = typer.Option(
        0,
        "--rt-priority",
        min=0,
        max=99,
        help="SCHED_FIFO priority of the control cycle (needs root/CAP_SYS_NICE); 0: off.",
    ),
) -> None:
    """Emulate a UR controller on 127.0.0.1 for ur_rtde (RTDE, dashboard, script upload), with faults on demand.

    Exit codes: 0 it ran until --duration; 1 one of its threads failed (the line says how); 2 a refused
    option or a port it could not bind; 128 + n a signal n (SIGINT 130, SIGTERM 143).
    """
    check_ur_arm(robot)
    # start-up time: only emulate-ur needs the emulator's servers
    from snac_gym.real.emulator import UREmulator
    from snac_gym.real.emulator.serve import fault_plan, parse_numbers, serve

    startup.imports_done()
    try:
        offset = None if tcp_offset is None else parse_numbers(tcp_offset, "--tcp-offset", (3, 6))
        start = None if q0 is None else _numbers("--q0", q0, 6)
        emulator = UREmulator(
            robot=robot,
            series=series,
            host=host,
            port_base=port_base,
            speed_scaling=speed_scaling,
            bind_timeout=0.0,
            rt_priority=rt_priority,
            tcp_offset=None if offset is None else (offset + [0.0, 0.0, 0.0])[:6],
            q0=start,
        )
        plan = fault_plan(
            protective_stop_at,
            emergency_stop_at,
            latency_spike,
            drop_at,
            stale_at,
            watchdog_expiry_at,
            drop_for,
            nonfinite_at,
        )
        for at, fault, args in plan:
            emulator.schedule(at, fault, *args)
        stopped_by = serve(emulator, duration, typer.echo)
    except (ValueError, OSError) as exc:
        typer.echo(
            f"error: {option_message(str(exc), _EMULATOR_OPTIONS) if isinstance(exc, ValueError) else exc}", err=True
        )
        raise typer.Exit(code=2) from exc
    if stopped_by is not None and emulator.failure is None:
        raise interrupted(TerminationSignal(stopped_by), "the emulator closed its connections; it keeps no files")
    if emulator.failure is not None:  # a thread of the emulator died: not a clean end
        failure = emulator.failure
        typer.echo(f"error: the emulator stopped: {type(failure).__name__}: {failure}", err=True)
        raise typer.Exit(code=1)


#: The options of ``emulate-ur`` whose refusals name the emulator's argument.
_EMULATOR_OPTIONS = {"port_base": "--port-base", "speed scaling": "--speed-scaling", "host": "--host"}
