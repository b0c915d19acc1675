"""The commands that run the simulated arm on this machine, ``demo`` (the paper's Figure 3) and ``bench``, and ``plot``,
which draws a demo's or a real run's figures again from its log."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from snac_gym.apps.commands.common import (
    check_controller,
    check_engine,
    check_robot,
    check_solver,
    check_task,
    interrupted,
    path_option,
    path_parser,
    registered_robots,
    registered_tasks,
)
from snac_gym.common import startup
from snac_gym.policies import available_policies

__all__ = ["bench", "demo", "plot"]


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

    startup.imports_done()
    try:  # both before the first measurement, which a bad --act-calls would otherwise follow by minutes
        check_bench_counts(steps, act_calls)
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    try:
        _bench(steps, panda, substeps, tracking, act, act_calls, vector)
    except KeyboardInterrupt as exc:  # bench writes no file: the tables printed so far are whole
        raise interrupted(exc, "bench writes no files; the tables printed above are complete") from None


def _bench(steps: int, panda: bool, substeps: bool, tracking: bool, act: bool, act_calls: int, vector: bool) -> None:
    # start-up time: only bench needs bench.py (threadpoolctl)
    from snac_gym.apps.bench import format_env_bench, left_out, run_env_bench, run_substep_study
    from snac_gym.common.machine import describe_machine, machine_info

    # a speed means little without the machine and its load: the same envs ran 1.5 times as fast on one 2-core
    # machine as on another
    typer.echo(f"machine: {describe_machine(machine_info())}\n")
    results = run_env_bench(steps=steps, include_panda=panda)
    typer.echo(format_env_bench(results))
    for line in left_out(results, include_panda=panda):
        typer.echo(line)
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


def demo(
    task: str = typer.Option(
        "reach",
        "--task",
        help=f"A registered task ({registered_tasks()}): reach is a fixed target, track the paper's circle.",
    ),
    controller: str = typer.Option("snac", "--controller", help="Any registered policy name."),
    out: Path = path_option(
        Path("demo_out"), "--out", "a folder", "Folder for the PNG panels, the log and summary.json."
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of the env and policy resets (a NumPy seed)."),
    steps: Optional[int] = typer.Option(
        None, "--steps", min=1, help="Control steps (default: 1500 reach = 12 s, 2500 track = 20 s)."
    ),
    duration: Optional[float] = typer.Option(
        None, "--duration", min=0.0, help="Horizon in seconds instead of --steps."
    ),
    csv: bool = typer.Option(False, "--csv", help="Also write the trajectory log as CSV."),
    plots: bool = typer.Option(True, "--plots/--no-plots", help="Write the PNG panels."),
    robot: str = typer.Option("ur10", "--robot", help=f"A registered robot: {registered_robots()} (docs/robots.md)."),
    model_error: Optional[str] = typer.Option(
        None,
        "--model-error",
        help="Give the controller a wrong arm model (as for evaluate); the simulated arm keeps the true one.",
    ),
    engine: str = typer.Option(
        "pybullet",
        "--engine",
        help="The arm's model: pybullet (the env's default), mujoco (the mujoco extra) or kinematic (the paper's "
        "exact θ += uΔt, as evaluate's default).",
    ),
    pybullet_solver: str = typer.Option(
        "pgs",
        "--pybullet-solver",
        help="How PyBullet solves its motors: pgs (the -v0 ids' iterated solve; under gravity each joint lags its "
        "command a little) or dantzig (the -v1 ids': θ̇ = u wherever a motor is within its force bound).",
    ),
) -> None:
    """Run the paper's reach or track demonstration (Figure 3) and print its figures of merit."""
    check_task(task)
    check_controller(controller)
    check_robot(robot)
    check_engine(engine)
    check_solver(pybullet_solver)
    if steps is not None and duration is not None:
        raise typer.BadParameter("give --steps or --duration, not both", param_hint="--steps")
    # start-up time: the demo loads numba, scipy and pandas (after the checks: a usage error comes at once)
    from snac_gym.apps.demo import run_demo

    startup.imports_done()
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
            engine=engine,
            pybullet_solver=pybullet_solver,
            progress=_stderr_line,
        )
    except ValueError as exc:  # unknown controller, --seed, --out and other bad input: a clean message, not a traceback
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    except KeyboardInterrupt as exc:  # a stop signal: run_demo says what it wrote (a partial run is marked so)
        raise interrupted(exc, getattr(exc, "kept", "nothing was written")) from None
    typer.echo(result.summary())


def _stderr_line(line: str) -> None:
    """A progress line on stderr, so that the figures of merit on stdout stay clean."""
    typer.echo(line, err=True)


def plot(
    log: Path = typer.Argument(
        ...,
        parser=path_parser("'LOG'", "a log or its folder", exists=True),
        metavar="LOG",
        help="A demo's or a real run's log (*_log.parquet), or the folder that holds it (its --out).",
    ),
    out: Optional[Path] = path_option(
        None, "--out", "a folder", "Folder for the PNG panels (default: the log's folder)."
    ),
) -> None:
    """Draw a demo's or a real run's figures from its log: those --no-plots or a stop signal left out."""
    # start-up time: the figures load matplotlib and pandas (after typer's checks: a usage error comes at once)
    from snac_gym.apps.figures import redraw_figures

    startup.imports_done()
    try:
        files = redraw_figures(log, out, say=lambda text: _stderr_line(f"plot: {text}"))
    except ValueError as exc:  # no such log, or not a log: one line naming it
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    except KeyboardInterrupt as exc:  # redraw_figures says how many it drew (each whole)
        raise interrupted(exc, getattr(exc, "kept", "no figure was drawn")) from None
    typer.echo(f"drew {len(files)} figures in {files[0].parent}/: {', '.join(f.name for f in files)}")
