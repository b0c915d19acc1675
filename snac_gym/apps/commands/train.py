"""The ``train-ppo`` command: the PPO baseline trained with stable-baselines3."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from snac_gym.apps.commands.common import (
    check_task,
    interrupted,
    option_message,
    path_option,
    registered_tasks,
)
from snac_gym.common.progress import wants_lines

__all__ = ["train_ppo_command"]


def train_ppo_command(
    task: str = typer.Option(..., "--task", help=f"A registered task ({registered_tasks()})."),
    timesteps: Optional[int] = typer.Option(
        None,
        "--timesteps",
        min=1,
        help="Total env steps (default: the config's), rounded up to whole PPO rollouts (n_envs × n_steps).",
    ),
    seed: Optional[int] = typer.Option(
        None, "--seed", help="Seed of PPO and the training envs (default: the config's)."
    ),
    out: Path = path_option(
        ..., "--out", "a folder", "Output folder: checkpoint/, best/, logs, evaluations.csv, curves."
    ),
    config: Optional[Path] = path_option(
        None, "--config", "a file", "Hyperparameter file (default: snac_gym/ppo/configs/TASK.json)."
    ),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out from its checkpoint."),
    init_from: Optional[Path] = path_option(
        None,
        "--init-from",
        "a policy file",
        "A policy file whose actor the new model starts from, e.g. a behaviour clone (default: the config's "
        "init_from).",
    ),
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
    check_task(task)
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
            init_from=init_from,
        )
    except (ValueError, ImportError) as exc:  # bad config, folder or checkpoint, missing [rl] extra: a clean message
        given = {
            key: option
            for key, option, value in (
                ("seed", "--seed", seed),
                ("vec_env.kind", "--vec-env", vec_env),
                ("vec_env.n_envs", "--n-envs", n_envs),
                ("timesteps", "--timesteps", timesteps),
                ("init_from", "--init-from", init_from),
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
        raise interrupted(exc, getattr(exc, "kept", kept)) from None
    if result.status == "interrupted":
        raise interrupted(
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
    named = option_message(rest, given) if sep else message
    return named if named != rest else message
