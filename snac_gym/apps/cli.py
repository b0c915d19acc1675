"""The ``snac-gym`` command: a thin face over importable functions.

Each subcommand parses its options and calls a function that can be used from Python as well.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional, cast

import typer

from snac_gym import __version__
from snac_gym.common._signals import STOP_SIGNALS, SignalGuard, TerminationSignal, exit_code
from snac_gym.common.progress import wants_lines
from snac_gym.model.robots import robot_names
from snac_gym.model.ur_models import UR_MODELS
from snac_gym.policies import available_policies
from snac_gym.tasks import get_task, task_names

if TYPE_CHECKING:
    from click import ClickException

# The help lists what is registered when the command starts (built-ins and the entry points of
# snac_gym.robots and snac_gym.tasks), not a copy written here.
_ROBOTS = ", ".join(robot_names())
_TASKS = ", ".join(task_names())
_UR_ARMS = ", ".join(UR_MODELS)

app = typer.Typer(
    name="snac-gym",
    help="SNAC kinematic control of UR arms: demos, the paper's evaluation, benchmarks.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # Click's plain help: rich's option tables cut long option names ("--unlock-protectiv…") at 80 columns.
    rich_markup_mode=None,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"snac-gym {__version__}")
        raise typer.Exit()


@app.callback()
def root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """SNAC kinematic control of UR arms: demos, the paper's evaluation, benchmarks."""


def _renamed_option(new: str, value: str, old: str, old_value: str | None, default: str) -> str:
    """The value of option ``new``, or of its hidden deprecated name ``old`` (a ``DeprecationWarning``).

    Raises:
        typer.BadParameter: If both are given with different values.
    """
    if old_value is None:
        return value
    warnings.warn(f"{old} is deprecated; use {new}", DeprecationWarning, stacklevel=2)
    if value not in (default, old_value):
        raise typer.BadParameter(f"give {new} only ({old} is its deprecated name)", param_hint=new)
    return old_value


def _option_message(message: str, fields: dict[str, str]) -> str:
    """``message`` with the field it starts with (``field must ...``, ``field (--option) must ...``) named by
    the option the user typed: ``clear_timeout must be ...`` is ``--recovery-timeout must be ...``."""
    for field, option in fields.items():
        for prefix in (f"{field} ({option}) ", f"{field} "):
            if message.startswith(prefix):
                return f"{option} {message[len(prefix) :]}"
    return message


def _check_task(task: str) -> None:
    """Refuse a ``--task`` that names no registered task."""
    if task not in task_names():
        raise typer.BadParameter(f"must be one of {sorted(task_names())}", param_hint="--task")


def _check_ur_arm(robot: str) -> None:
    """Refuse a ``--robot`` of ``real`` or ``emulate-ur`` that is not a UR arm."""
    if robot not in UR_MODELS:
        raise typer.BadParameter(f"{robot!r} is not a UR model; choose one of {_UR_ARMS}", param_hint="--robot")


def _check_controller(controller: str) -> None:
    """Refuse a ``--controller`` that names no registered policy (before any env is built for it)."""
    if controller not in available_policies():
        raise typer.BadParameter(
            f"unknown policy {controller!r}; available: {', '.join(available_policies())}", param_hint="--controller"
        )


@app.command()
def bench(
    steps: int = typer.Option(
        5000,
        "--steps",
        help="Env steps per measurement, 100 to 1,000,000 (each env is timed 5 times: ~20 min for the UR10's two "
        "ids in both engines at the bound).",
    ),
    panda: bool = typer.Option(
        True, help="Also measure panda-gym's PandaReachJoints-v3 (if installed) for comparison."
    ),
    substeps: bool = typer.Option(False, "--substeps", help="Also run the physics-substep accuracy study."),
    tracking: bool = typer.Option(
        False,
        "--tracking",
        help="Also measure how closely PyBullet and MuJoCo follow the exact kinematic model under random commands "
        "(UR10 and Panda, 5 episodes each).",
    ),
    act: bool = typer.Option(False, "--act", help="Also time one act() call of every available policy that imports."),
    act_calls: int = typer.Option(
        5000,
        "--act-calls",
        help="Timed act() calls per policy and task, 100 to 1,000,000 (timings kept in memory, 8 B each; ~100 s "
        "per policy and task at the bound).",
    ),
    vector: bool = typer.Option(
        False, "--vector", help="Also measure the batched kinematic vector env (N = 1, 64, 1024, 4096)."
    ),
) -> None:
    """Env steps per second and real-time factor of both ids, in PyBullet and MuJoCo, on one core (and, with --act, act
    latency)."""
    # start-up time: only bench needs bench.py (threadpoolctl)
    from snac_gym.apps.bench import check_bench_counts

    try:  # both before the first measurement, which a bad --act-calls would otherwise follow by minutes
        check_bench_counts(steps, act_calls)
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    try:
        _bench(steps, panda, substeps, tracking, act, act_calls, vector)
    except KeyboardInterrupt as exc:  # bench writes no file: the tables printed so far are whole
        raise _interrupted(exc, "bench writes no files; the tables printed above are complete") from None


def _bench(steps: int, panda: bool, substeps: bool, tracking: bool, act: bool, act_calls: int, vector: bool) -> None:
    # start-up time: only bench needs bench.py (threadpoolctl)
    from snac_gym.apps.bench import format_env_bench, run_env_bench, run_substep_study

    typer.echo(format_env_bench(run_env_bench(steps=steps, include_panda=panda)))
    if vector:
        # start-up time: only bench needs bench.py
        from snac_gym.apps.bench import format_vector_bench, run_vector_bench

        typer.echo(
            "\nbatched kinematic vector env (gym.make_vec(..., vectorization_mode='vector_entry_point')), one core"
        )
        typer.echo(format_vector_bench(run_vector_bench()))
    if tracking:
        # start-up time: only bench needs bench.py
        from snac_gym.apps.bench import format_tracking_study, run_tracking_study

        typer.echo("\nfollowing the exact kinematic model θₖ₊₁ = θₖ + uₖΔt over 1000 steps, worst of 5 episodes")
        typer.echo(format_tracking_study(run_tracking_study()))
    if substeps:
        typer.echo("\nphysics substeps: deviation from exact integration θ += u·dt over 1000 steps")
        for row in run_substep_study():
            typer.echo(
                f"  n_substeps={row['n_substeps']} ({row['physics_dt_ms']:.1f} ms): max |Δθ| = "
                f"{row['max_joint_position_error_rad']:.2e} rad, max |θ̇ − u| = "
                f"{row['max_joint_velocity_error_rad_s']:.2e} rad/s, {row['steps_per_s']:.0f} steps/s"
            )
    if act:
        # start-up time: only bench needs bench.py
        from snac_gym.apps.bench import format_act_bench, run_act_bench

        typer.echo("\nact latency on one core, closed loop from the paper's θ0 (goal: median ≤ 20 µs, p99 ≤ 100 µs)")
        typer.echo(format_act_bench(run_act_bench(names=available_policies(), calls=act_calls)))


@app.command()
def demo(
    task: str = typer.Option(
        "reach", "--task", help=f"A registered task ({_TASKS}): reach is a fixed target, track the paper's circle."
    ),
    controller: str = typer.Option("snac", "--controller", help="Any registered policy name."),
    out: Path = typer.Option(Path("demo_out"), "--out", help="Folder for the PNG panels, the log and summary.json."),
    seed: int = typer.Option(0, "--seed", help="Seed of the env and policy resets (a NumPy seed)."),
    steps: Optional[int] = typer.Option(
        None, "--steps", min=1, help="Control steps (default: 1500 reach = 12 s, 2500 track = 20 s)."
    ),
    duration: Optional[float] = typer.Option(
        None, "--duration", min=0.0, help="Horizon in seconds instead of --steps."
    ),
    csv: bool = typer.Option(False, "--csv", help="Also write the trajectory log as CSV."),
    plots: bool = typer.Option(True, "--plots/--no-plots", help="Write the PNG panels."),
    robot: str = typer.Option("ur10", "--robot", help=f"A registered robot: {_ROBOTS} (docs/robots.md)."),
    model_error: Optional[str] = typer.Option(
        None,
        "--model-error",
        help="Give the controller a wrong arm model (as for evaluate); the simulated arm keeps the true one.",
    ),
) -> None:
    """Run the paper's reach or track demonstration (Figure 3) and print its figures of merit."""
    # start-up time: the demo loads numba, scipy and pandas
    from snac_gym.apps.demo import run_demo

    _check_task(task)
    _check_controller(controller)
    if steps is not None and duration is not None:
        raise typer.BadParameter("give --steps or --duration, not both", param_hint="--steps")
    try:
        result = run_demo(
            task=task,
            controller=controller,
            out_dir=out,
            seed=seed,
            steps=steps,
            duration=duration,
            csv=csv,
            plots=plots,
            robot=robot,
            model_error=model_error,
        )
    except ValueError as exc:  # unknown controller, --seed, --out and other bad input: a clean message, not a traceback
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    except KeyboardInterrupt as exc:  # a stop signal: run_demo says what it wrote (a partial run is marked so)
        raise _interrupted(exc, getattr(exc, "kept", "nothing was written")) from None
    typer.echo(result.summary())


@app.command()
def real(
    host: Optional[str] = typer.Option(None, "--host", help="IP of the UR controller (--connection rtde)."),
    task: str = typer.Option(
        "reach", "--task", help=f"A registered task ({_TASKS}): the demo's start pose and reference."
    ),
    controller: str = typer.Option("snac", "--controller", help="Any registered policy name."),
    out: Path = typer.Option(Path("real_out"), "--out", help="Folder for the log, the panels and the loop timing."),
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
        "ur10", "--robot", help=f"The UR arm: {_UR_ARMS} (its kinematics, datasheet limits and default task box)."
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
    # start-up time (apps.real: pandas, numba); tests swap SafetyLimits
    from snac_gym.apps.real import run_real_episode
    from snac_gym.real import ConnectionFailure, SafetyLimits
    from snac_gym.real.loop_tuning import LoopTuning
    from snac_gym.real.recovery import RecoveryLimits

    _check_task(task)
    _check_controller(controller)
    _check_ur_arm(robot)
    connection = _renamed_option("--connection", connection, "--backend", backend, "rtde")
    try:
        try:
            recovery = RecoveryLimits(max_recoveries, unlock_protective_stop, recovery_timeout, reconnect_timeout)
        except ValueError as exc:  # the limits' own field names, told by their options'
            raise ValueError(_option_message(str(exc), _REAL_OPTIONS)) from None
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
        )
    except BaseException as exc:  # every way out: one line and a code of its own, never a traceback or a signal
        where = f"; the log so far is in {cast(Any, exc).log_dir}/" if getattr(exc, "log_dir", None) else ""
        line = str(exc).splitlines()[0] if str(exc) else ""
        if isinstance(exc, KeyboardInterrupt):  # Ctrl-C and the other stop signals: the arm was stopped
            raise _interrupted(exc, f"the arm was stopped{where or ' (before the episode: nothing logged)'}") from None
        if isinstance(exc, ConnectionFailure):  # the link or the ur_rtde client was lost: exit 1
            typer.echo(f"error: {line}{where}", err=True)
            raise typer.Exit(code=1) from None
        if isinstance(exc, (ValueError, RuntimeError)):
            typer.echo(
                f"error: {_option_message(line, _REAL_OPTIONS) if isinstance(exc, ValueError) else line}{where}",
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


@app.command("emulate-ur")
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
    robot: str = typer.Option("ur10", "--robot", help=f"Arm model: {_UR_ARMS} (the UR controller emulated)."),
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
    _check_ur_arm(robot)
    # start-up time: only emulate-ur needs the emulator's servers
    from snac_gym.real.emulator import UREmulator
    from snac_gym.real.emulator.serve import fault_plan, parse_numbers, serve

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
            f"error: {_option_message(str(exc), _EMULATOR_OPTIONS) if isinstance(exc, ValueError) else exc}", err=True
        )
        raise typer.Exit(code=2) from exc
    if stopped_by is not None and emulator.failure is None:
        raise _interrupted(TerminationSignal(stopped_by), "the emulator closed its connections; it keeps no files")
    if emulator.failure is not None:  # a thread of the emulator died: not a clean end
        failure = emulator.failure
        typer.echo(f"error: the emulator stopped: {type(failure).__name__}: {failure}", err=True)
        raise typer.Exit(code=1)


#: The options of ``emulate-ur`` whose refusals name the emulator's argument.
_EMULATOR_OPTIONS = {"port_base": "--port-base", "speed scaling": "--speed-scaling"}


#: The stop-signal guard :func:`main` holds for the whole command (``None`` where the app is called
#: without it, as by click's test runner: then only Ctrl-C interrupts, as Python's default).
_main_guard: SignalGuard | None = None


#: Whether the command said it was interrupted (:func:`_interrupted`), so that :func:`main` does not say it again.
_reported: list[str] = []


def _interrupted(exc: BaseException, kept: str, during: str = "") -> typer.Exit:
    """Say in one line which signal ended the command (and ``during`` what) and what it kept; return the exit to raise
    (128 + n)."""
    name = (_main_guard or SignalGuard()).signal_name(exc)
    _reported.append(name)
    typer.echo(f"interrupted by {name}{' ' + during if during else ''}: {kept}", err=True)
    return typer.Exit(code=exit_code(name))


@app.command()
def evaluate(
    out: str = typer.Option("runs/evaluation", "--out", help="Output folder (results, summary, plots, parts)."),
    task: str = typer.Option(
        "both",
        "--task",
        help=f"both (reach and track, Table I), a registered task ({_TASKS}), or a pose task, pose-reach or "
        "pose-track (docs/robots.md).",
    ),
    controllers: Optional[str] = typer.Option(
        None,
        "--controllers",
        help="Comma-separated policy names (default: every registered one); `optimal` adds the per-sample optimum "
        "as a reference row (docs/optimal.md).",
    ),
    samples: Optional[int] = typer.Option(
        None,
        "--samples",
        min=1,
        help="Random samples per task (default 1000, the paper's; at most what half the memory holds).",
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of the sample set and of every policy reset."),
    horizon: list[str] = typer.Option(
        [], "--horizon", help="SECONDS for every task, or TASK=SECONDS (repeatable). Default reach=12, track=20."
    ),
    engine: str = typer.Option(
        "kinematic",
        "--engine",
        help="kinematic (exact θ += uΔt, all samples in lockstep, fast), mujoco or pybullet (one simulated arm "
        "per sample with that physics, in lockstep; mujoco needs the mujoco extra).",
    ),
    backend: Optional[str] = typer.Option(None, "--backend", hidden=True, help="Deprecated name of --engine."),
    match_effort: bool = typer.Option(
        True, "--match-effort/--no-match-effort", help="Calibrate every controller to equal control effort."
    ),
    effort_reference: Optional[str] = typer.Option(
        None,
        "--effort-reference",
        help="Controller whose effort the others are matched to (default: snac if evaluated, else the first "
        "controller).",
    ),
    effort_statistic: str = typer.Option(
        "mean-peak",
        "--effort-statistic",
        help="What equal effort equalises: mean-peak (the mean over the samples of each rollout's peak |u|/limit; "
        "the default), max (the maximum |u| over the sample set, rad/s), median-peak (the median rollout's "
        "peak |u|/limit) or peak-ratio (each rollout's peak over the reference's on the same sample, "
        "geometric mean).",
    ),
    effort_target: Optional[float] = typer.Option(
        None,
        "--effort-target",
        help="Explicit effort target in the statistic's unit (rad/s for max, a fraction for mean-peak and "
        "median-peak; not for peak-ratio); then every controller is matched.",
    ),
    effort_tolerance: float = typer.Option(0.02, "--effort-tolerance", help="Relative tolerance of the effort match."),
    effort_samples: Optional[int] = typer.Option(
        None,
        "--effort-samples",
        min=0,
        help="Match equal effort on the first N samples of the seed's stream even when fewer are evaluated, so "
        "the matched knobs do not depend on --samples (default 1000; 0: on the evaluated samples).",
    ),
    calibration_samples: Optional[int] = typer.Option(
        None,
        "--calibration-samples",
        min=1,
        help="Samples the knob search runs on (default: all, fewer for controllers whose effort peaks late).",
    ),
    samples_file: Optional[Path] = typer.Option(
        None, "--samples-file", help="Read the samples from this CSV (docs/evaluation.md)."
    ),
    export_samples: Optional[Path] = typer.Option(
        None, "--export-samples", help="Also write the sample set to this CSV."
    ),
    export_only: bool = typer.Option(False, "--export-only", help="Only write --export-samples, run nothing."),
    save_trajectories: bool = typer.Option(
        False, "--save-trajectories", help="Write every rollout's per-step log under OUT/trajectories."
    ),
    workers: int = typer.Option(1, "--workers", min=1, help="Local worker processes."),
    ray: Optional[str] = typer.Option(
        None,
        "--ray",
        help="Run on Ray: 'local' (a new instance here) or a cluster address ('auto', 'ray://host:10001').",
    ),
    resume: bool = typer.Option(False, "--resume", help="Continue an interrupted run in OUT."),
    chunk_size: Optional[int] = typer.Option(
        None, "--chunk-size", min=1, help="Samples per job of a full pass (default 500; results do not depend on it)."
    ),
    cuboid: Optional[str] = typer.Option(
        None, "--cuboid", help="Sample cuboid x0,y0,z0,x1,y1,z1 in m (default: the UR10 box, docs/evaluation.md)."
    ),
    sample_space: str = typer.Option(
        "cuboid",
        "--sample-space",
        help="cuboid (Table I's box in front of the arm, or --cuboid) or workspace (anywhere the arm reaches, "
        "every IK branch).",
    ),
    robot: str = typer.Option("ur10", "--robot", help=f"A registered robot: {_ROBOTS} (docs/robots.md)."),
    param: list[str] = typer.Option(
        [], "--param", help="Controller argument CONTROLLER.KEY=VALUE (repeatable), e.g. svf.nu=5."
    ),
    batch: bool = typer.Option(True, "--batch/--no-batch", help="Use a policy's act_batch protocol when it has one."),
    progress: bool = typer.Option(
        True,
        "--progress/--no-progress",
        help="Show progress on stderr: a bar on a terminal, else a line every 10 % or 10 s.",
    ),
    plots: bool = typer.Option(
        True,
        "--plots/--no-plots",
        help="Draw cost_boxplot.png (and a sweep's tradeoff.png); --no-plots: the tables and summary only.",
    ),
    cost: str = typer.Option(
        "table1",
        "--cost",
        help="table1 (Σ (eᵀQe + uᵀRu + u̇ᵀRu̇) Δt, the paper's Table I) or hjb (Σ (eᵀQe + uᵀRu) Δt, the cost of "
        "eqs. 6/32); `optimal` solves for it.",
    ),
    udot_start: str = typer.Option(
        "rest", "--udot-start", help="u₋₁ of the u̇ term: rest (0: the jump from rest counts) or first (u₀)."
    ),
    q_scale: float = typer.Option(
        1.0,
        "--q-scale",
        help="Q = q·I in the cost (1e6 prices the error in mm²); given to the controllers that take Q.",
    ),
    success_threshold: float = typer.Option(
        0.95, "--success-threshold", help="Success rate a controller needs to be ranked in the summary."
    ),
    model_error: Optional[str] = typer.Option(
        None,
        "--model-error",
        help="Give the controllers a wrong arm model, parts joined by ';': 'joint_offset=a0,...,a5' (rad), "
        "'link_scale=s' (relative), 'link_length=d0,...,d5' (m, per placement), "
        "'joint_axis_tilt=a0,...,a5[,b0,...,b5]' (rad), 'base=x,y,z,rx,ry,rz' (m, rad), 'tool_offset=x,y,z' "
        "(m, tool frame), 'random=sigma,seed' (a random rigid error of every placement and the tool), "
        "'model=NAME' (another robot's kinematics, e.g. ur5; same joint count). The plant, the cost, the "
        "success rule and the optimum keep the true model.",
    ),
    reference_limits: str = typer.Option(
        "joints",
        "--reference-limits",
        help="Constraints of the `optimal` reference: joints (joint position and velocity limits, as the success "
        "rule counts) or velocity (velocity limits only; its label says so).",
    ),
    reference_cache: bool = typer.Option(
        True,
        "--reference-cache/--no-reference-cache",
        help="Reuse the `optimal` rows cached by sample content (~/.cache/snac-gym/reference, or "
        "$SNAC_GYM_CACHE_DIR), keyed by everything they depend on, the code included; --no-reference-cache "
        "solves every sample anew.",
    ),
    recalibrate: bool = typer.Option(
        False,
        "--recalibrate",
        help="Match the effort anew even where an earlier run with the same effort set, settings and code cached "
        "its knobs (~/.cache/snac-gym/calibration, or $SNAC_GYM_CACHE_DIR), and overwrite them.",
    ),
    sweep: bool = typer.Option(
        False,
        "--sweep/--no-sweep",
        help="Also run each controller over its effort knob: OUT/sweep.csv and OUT/tradeoff.png (cost against "
        "success, error and peak effort; docs/evaluation.md).",
    ),
    sweep_points: Optional[int] = typer.Option(
        None,
        "--sweep-points",
        help="Knob values per controller and task in the sweep (2 to 25; default 7), plus the equal-effort point.",
    ),
    sweep_span: Optional[float] = typer.Option(
        None,
        "--sweep-span",
        help="The sweep's knob grid reaches default/SPAN to default*SPAN, geometrically (default 4).",
    ),
) -> None:
    """The paper's quantitative test (Table I): trajectory cost V/N of every controller on random samples."""
    engine = _renamed_option("--engine", engine, "--backend", backend, "kinematic")
    out_dir: Path | None = None
    start: float | None = None
    try:
        # start-up time: the evaluation loads numba, scipy and pandas
        from snac_gym.evaluation.options import (
            check_option_combinations,
            parse_controllers,
            parse_horizons,
            parse_out,
            parse_params,
            parse_sample_space,
            parse_tasks,
        )
        from snac_gym.evaluation.run_config import EvaluationConfig
        from snac_gym.evaluation.runner import export_sample_set, run_evaluation
        from snac_gym.evaluation.sweep import run_sweep

        out_dir = parse_out(out)
        tasks, names = parse_tasks(task), parse_controllers(controllers)
        check_option_combinations(
            samples=samples,
            cuboid=cuboid,
            samples_file=samples_file,
            export_samples=export_samples,
            sweep=sweep,
            sweep_points=sweep_points,
            sweep_span=sweep_span,
            effort_reference=effort_reference,
            match_effort=match_effort,
            effort_target=effort_target,
            controllers=names,
            sample_space=sample_space,
            effort_samples=effort_samples,
        )
        space = parse_sample_space(sample_space, cuboid, robot)
        _check_export_folder(export_samples)
        config = EvaluationConfig(
            out=out_dir,
            tasks=tasks,
            controllers=names,
            samples=1000 if samples is None else samples,
            seed=seed,
            horizons=parse_horizons(horizon, tasks),
            engine=engine,
            match_effort=match_effort,
            effort_reference=effort_reference or "snac",
            effort_statistic=effort_statistic,
            effort_target=effort_target,
            effort_tolerance=effort_tolerance,
            calibration_samples=calibration_samples,
            samples_file=samples_file,
            **({} if effort_samples is None else {"effort_samples": effort_samples}),
            export_samples=export_samples,
            save_trajectories=save_trajectories,
            workers=workers,
            ray_address=ray,
            resume=resume,
            robot=robot,
            space=space,
            controller_kwargs=parse_params(param),
            progress=progress,
            plots=plots,
            use_batch=batch,
            cost=cost,
            udot_start=udot_start,
            q_scale=q_scale,
            success_threshold=success_threshold,
            model_error=model_error,
            reference_limits=reference_limits,
            reference_cache=reference_cache,
            recalibrate=recalibrate,
            **({} if chunk_size is None else {"chunk_size": chunk_size}),
        )
        _validate_naming_options(config)
        start = time.perf_counter()
        if export_only:
            typer.echo(f"samples written to {export_sample_set(config)}")
            return
        if sweep:
            run_sweep(
                config,
                points=7 if sweep_points is None else sweep_points,
                span=4.0 if sweep_span is None else sweep_span,
            )
        else:
            run_evaluation(config)
    except (
        ValueError,
        RuntimeError,
        OSError,
    ) as exc:  # bad options, samples file, controller, output folder: a clean message
        typer.echo(f"error: {_with_option(str(exc)) if isinstance(exc, ValueError) else exc}", err=True)
        raise typer.Exit(code=2) from None
    except KeyboardInterrupt as exc:  # a stop signal: the workers are stopped, finished jobs are kept
        if start is None:  # in the imports or the option checks
            raise _interrupted(exc, "nothing was written; run the command again", "before the run started") from None
        if out_dir is not None and (out_dir / "run.json").exists():
            raise _interrupted(exc, f"finished jobs are kept in {out_dir}/; continue with --resume") from None
        # the run is recorded once its sample set is complete: nothing to resume yet
        raise _interrupted(exc, "nothing to resume; run the command again", "while drawing the samples") from None
    summary = (out_dir / "summary.md").read_text()
    typer.echo(summary.split("\n## ")[0].rstrip())
    for line in summary.splitlines():  # an unmatched effort makes the comparison unequal: say so on stderr too
        if line.startswith("**Warning:**"):
            typer.echo("warning: " + line.removeprefix("**Warning:**").strip(), err=True)
    if sweep:
        figure = f" and {out_dir / 'tradeoff.png'}" if plots else ""
        typer.echo(f"\ntrade-off sweep: {out_dir / 'sweep.csv'}{figure}")
    written = "results, summary and plots" if plots else "results and summary"
    typer.echo(f"\nwall time {time.perf_counter() - start:.1f} s; {written} in {out_dir}/")


#: The fields of :class:`~snac_gym.evaluation.run_config.EvaluationConfig` set by an ``evaluate`` option of another name
#: (the others are the field with dashes: ``effort_tolerance`` is ``--effort-tolerance``).
_EVALUATE_RENAMED = {
    "ray_address": "--ray",
    "use_batch": "--batch",
    "horizons": "--horizon",
    "controller_kwargs": "--param",
}


def _evaluate_message(message: str) -> str:
    """An :class:`EvaluationConfig` refusal naming the option: ``q_scale must be ...`` is ``--q-scale must be ...``;
    a refusal that names no field (``unknown robot 'x'``) gets its option in front."""
    from snac_gym.evaluation.run_config import EvaluationConfig  # start-up time: only when a refusal is shown

    fields = {
        item.name: _EVALUATE_RENAMED.get(item.name, "--" + item.name.replace("_", "-"))
        for item in dataclasses.fields(EvaluationConfig)
    }
    named = _option_message(message, fields)
    return named if named != message else _with_option(message)


def _with_option(message: str) -> str:
    """An ``evaluate`` refusal that names no option, with the option in front: ``--robot: unknown robot 'x'; ...``."""
    for start, option in (("unknown robot", "--robot"), ("unknown controller", "--controllers"), ("the ", "--horizon")):
        if message.startswith(start) and (option != "--horizon" or " horizon must be" in message):
            return f"{option}: {message}"
    return message


def _validate_naming_options(config: Any) -> None:
    """``config.validate()`` here, to name the options in a refusal (the run validates it again)."""
    try:
        config.validate()
    except ValueError as exc:
        raise ValueError(_evaluate_message(str(exc))) from None


def _check_export_folder(path: Path | None) -> None:
    """Refuse an ``--export-samples`` file whose folder cannot be made: a missing folder is created when the samples
    are written, but one under a file (or a dangling link) would fail late with a bare ``[Errno 2]`` or
    ``[Errno 20]``."""
    if path is None:
        return
    folder = Path(path).parent
    for above in (folder, *folder.parents):
        if above.is_dir():
            return
        if above.exists() or above.is_symlink():
            raise ValueError(
                f"--export-samples {path}: its folder {folder} cannot be made, {above} is not a folder; "
                "choose another file"
            )


@app.command("train-ppo")
def train_ppo_command(
    task: str = typer.Option(..., "--task", help=f"A registered task ({_TASKS})."),
    timesteps: Optional[int] = typer.Option(
        None, "--timesteps", min=1, help="Total env steps (default: the config's)."
    ),
    seed: Optional[int] = typer.Option(
        None, "--seed", help="Seed of PPO and the training envs (default: the config's)."
    ),
    out: Path = typer.Option(..., "--out", help="Output folder: checkpoint/, best/, logs, evaluations.csv, curves."),
    config: Optional[Path] = typer.Option(
        None, "--config", help="Hyperparameter file (default: snac_gym/ppo/configs/TASK.json)."
    ),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out from its checkpoint."),
    n_envs: Optional[int] = typer.Option(
        None, "--n-envs", min=1, max=1024, help="Parallel training envs (default: the config's)."
    ),
    vec_env: Optional[str] = typer.Option(
        None,
        "--vec-env",
        help="dummy (one process), subproc (one process per env) or batched (all episodes at once on the "
        "kinematic model).",
    ),
    progress: bool = typer.Option(
        True,
        "--progress/--no-progress",
        help="Progress lines on stderr (timesteps, time, success) where stderr is not a terminal.",
    ),
) -> None:
    """Train the PPO baseline (stable-baselines3) on a snac-gym env; keeps the best model. Needs stable-baselines3 and
    torch (the rl extra)."""
    _check_task(task)
    try:
        from snac_gym.ppo.train import train_ppo  # start-up time: the trainer loads pandas

        lines = (lambda text: typer.echo(text, err=True)) if progress and wants_lines() else None
        result = train_ppo(
            task=task,
            out=out,
            timesteps=timesteps,
            seed=seed,
            config_path=config,
            resume=resume,
            n_envs=n_envs,
            vec_env=vec_env,
            log=typer.echo,
            progress=lines,
        )
    except (ValueError, ImportError) as exc:  # bad config, folder or checkpoint, missing [rl] extra: a clean message
        given = {
            key: option
            for key, option, value in (
                ("seed", "--seed", seed),
                ("vec_env.kind", "--vec-env", vec_env),
                ("vec_env.n_envs", "--n-envs", n_envs),
                ("timesteps", "--timesteps", timesteps),
            )
            if value is not None
        }
        typer.echo(f"error: {_ppo_message(str(exc), given) if isinstance(exc, ValueError) else exc}", err=True)
        raise typer.Exit(code=2) from None
    except KeyboardInterrupt as exc:  # before training started (or in the curves after it finished)
        kept = (
            "the checkpoint is unchanged; run the command again"
            if resume
            else "nothing was trained; run the command again"
        )
        raise _interrupted(exc, getattr(exc, "kept", kept)) from None
    if result.status == "interrupted":
        raise _interrupted(
            KeyboardInterrupt(),
            f"checkpoint of {result.timesteps} timesteps saved in {out / 'checkpoint'}/ with every "
            f"evaluation so far; continue with --resume --out {out}",
            "during training",
        )
    best = result.best
    typer.echo(f"{result.status}: {result.timesteps} timesteps, wall time {result.wall_time_s / 60:.1f} min")
    if best is not None:
        typer.echo(
            f"best policy ({int(best['timesteps'])} timesteps, success {100 * best['success_rate']:.1f}%): "
            f"{result.best_policy}"
        )


def _ppo_message(message: str, given: dict[str, str]) -> str:
    """A config refusal (``CONFIG: seed must be ...``) of a value an option gave, naming the option instead
    (``--seed must be ...``); a value from the config file keeps the file's name and key."""
    path, sep, rest = message.partition(": ")
    named = _option_message(rest, given) if sep else message
    return named if named != rest else message


#: Where the classes :func:`main` catches live: typer 0.29 and later carry their own copy of click
#: (``typer._click``, and ``typer.Abort``) and raise its exceptions; older typers raise the standalone
#: click's. Both are looked up, each where it imports, so that neither version's errors escape as a traceback.
_CLICK_ERRORS = (("typer._click.exceptions", "ClickException"), ("click.exceptions", "ClickException"))
_CLICK_ABORTS = (("typer.exceptions", "Abort"), ("typer._click.exceptions", "Abort"), ("click.exceptions", "Abort"))


def _classes(places: tuple[tuple[str, str], ...]) -> tuple[type[BaseException], ...]:
    """The exception classes at ``places`` ((module, name) pairs) that exist here, each once."""
    import importlib  # only when a usage error reaches main(): nothing for a command that runs

    found: list[type[BaseException]] = []
    for module, name in places:
        try:
            cls = getattr(importlib.import_module(module), name, None)
        except ImportError:  # a typer without its own click, or no standalone click
            continue
        if isinstance(cls, type) and issubclass(cls, BaseException) and cls not in found:
            found.append(cls)
    return tuple(found)


def _click_errors() -> tuple[type[ClickException], ...]:
    """The ``ClickException`` classes of typer's own click and of the standalone click (those that import)."""
    return cast("tuple[type[ClickException], ...]", _classes(_CLICK_ERRORS))  # typer._click: a copy of it


def _click_aborts() -> tuple[type[BaseException], ...]:
    """The ``Abort`` classes (end of input at a prompt) of typer and of the standalone click (those that import)."""
    return _classes(_CLICK_ABORTS)


def _error_line(exc: ClickException) -> str:
    """A click error as one line: ``snac-gym COMMAND: error: MESSAGE (see 'snac-gym COMMAND --help')``.

    Click's own form is its usage block, a hint and the message on three or more lines; a script
    reading stderr gets one line here that names the command and, for a bad option, the option.
    """
    ctx = getattr(exc, "ctx", None)
    command = getattr(ctx, "command_path", None) or "snac-gym"  # no context: an error raised outside a command
    message = " ".join(part.strip() for part in exc.format_message().splitlines() if part.strip())
    line = f"{command}: error: {message}"
    help_names = getattr(ctx, "help_option_names", None)
    if ctx is not None and help_names:
        line += f" (see '{command} {help_names[0]}')"
    return line


def main() -> None:
    """Entry point of the ``snac-gym`` console script.

    A usage error (a bad or unknown option, a value a command refuses with ``typer.BadParameter``)
    is one line on stderr naming the command and the option, and exit 2; no traceback.

    SIGINT, SIGTERM, SIGHUP and SIGQUIT end every command the same way from its first line: one
    line on stderr saying what was interrupted and what was kept, and exit 128 + the signal's
    number. Each command says what it kept; a signal before a command started (in the option
    parsing) finds nothing written. It ends the process: the handlers stay, deferred, so that a
    signal while the interpreter exits is recorded instead of killing it mid-exit.
    """
    global _main_guard

    guard = SignalGuard()
    guard.install(STOP_SIGNALS)  # not restored: a signal while the process exits must not kill it mid-exit
    _main_guard = guard
    _reported.clear()
    interrupt: BaseException | None = None
    try:
        code = app(standalone_mode=False)
    except KeyboardInterrupt as exc:  # while typer built the command, before click's main
        code, interrupt = 130, exc
    except _click_errors() as exc:  # looked up only when an exception gets here (the standalone click too)
        if type(exc).__name__ == "NoArgsIsHelpError":  # `snac-gym` alone: the help, as in standalone mode
            exc.show()
        else:  # a usage error: one line naming the command and the option, not click's usage block
            typer.echo(_error_line(exc), err=True)
        code = exc.exit_code
    except _click_aborts():  # end of input at a prompt
        typer.echo("Aborted!", err=True)
        code = 1
    finally:
        guard.defer()  # the command has ended: a later signal is only recorded
        _main_guard = None
    if code == 130 and not _reported:  # typer's own exit for a KeyboardInterrupt no command caught
        name = guard.signal_name(interrupt)
        typer.echo(f"interrupted by {name} while the command was starting: nothing was written", err=True)
        code = exit_code(name)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":  # pragma: no cover
    main()
