"""The ``snac-gym`` command: a thin face over importable functions.

Each subcommand parses its options and calls a function that can be used from Python as well.
"""

from __future__ import annotations

import typer

app = typer.Typer(
    name="snac-gym",
    help="SNAC kinematic control of UR arms: demos, the paper's evaluation, benchmarks.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        from snac_gym import __version__

        typer.echo(f"snac-gym {__version__}")
        raise typer.Exit()


@app.callback()
def root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version and exit."),
) -> None:
    """SNAC kinematic control of UR arms: demos, the paper's evaluation, benchmarks."""


@app.command()
def bench(
    steps: int = typer.Option(5000, min=100, help="Env steps per measurement."),
    panda: bool = typer.Option(True, help="Also measure panda-gym's PandaReachJoints-v3 (if installed) for comparison."),
    substeps: bool = typer.Option(False, "--substeps", help="Also run the physics-substep accuracy study."),
) -> None:
    """Env steps per second and real-time factor of both ids on one core."""
    from snac_gym.bench import format_env_bench, run_env_bench, run_substep_study

    typer.echo(format_env_bench(run_env_bench(steps=steps, include_panda=panda)))
    if substeps:
        typer.echo("\nphysics substeps: deviation from exact integration θ += u·dt over 1000 steps")
        for row in run_substep_study():
            typer.echo(
                f"  n_substeps={row['n_substeps']} ({row['physics_dt_ms']:.1f} ms): max |Δθ| = "
                f"{row['max_joint_position_error_rad']:.2e} rad, max |θ̇ − u| = "
                f"{row['max_joint_velocity_error_rad_s']:.2e} rad/s, {row['steps_per_s']:.0f} steps/s"
            )


def main() -> None:
    """Entry point of the ``snac-gym`` console script."""
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
