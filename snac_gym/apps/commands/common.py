"""What the ``snac-gym`` commands share: the registered names their help lists, the checks of the options
several commands take, and the one-line report of a stop signal.

:func:`snac_gym.apps.cli.main` holds the signal guard for the whole command (:data:`main_guard`) and reads
:data:`reported` to know whether the command already said it was interrupted.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import typer

from snac_gym.common._signals import SignalGuard, exit_code
from snac_gym.model.robots import robot_names
from snac_gym.model.ur_models import UR_MODELS
from snac_gym.physics.base import PHYSICS, PYBULLET_SOLVERS
from snac_gym.policies import available_policies
from snac_gym.tasks import task_names

__all__ = [
    "UR_ARMS",
    "check_controller",
    "check_engine",
    "check_robot",
    "check_solver",
    "check_task",
    "check_ur_arm",
    "interrupted",
    "main_guard",
    "option_message",
    "path_option",
    "path_parser",
    "registered_robots",
    "registered_tasks",
    "renamed_option",
    "reported",
]

#: The UR arms ``real`` and ``emulate-ur`` drive, as their help lists them.
UR_ARMS = ", ".join(UR_MODELS)


def registered_robots() -> str:
    """The registered robots as the help lists them: what is registered when the command starts (built-ins and
    the entry points of snac_gym.robots), not a copy written here."""
    return ", ".join(robot_names())


def registered_tasks() -> str:
    """The registered tasks as the help lists them (built-ins and the entry points of snac_gym.tasks)."""
    return ", ".join(task_names())


def renamed_option(new: str, value: str, old: str, old_value: str | None, default: str) -> str:
    """The value of option ``new``, or of its hidden deprecated name ``old``: a ``DeprecationWarning`` for a caller
    in Python and a line on stderr for one at the shell, where Python hides that warning.

    Raises:
        typer.BadParameter: If both are given with different values.
    """
    if old_value is None:
        return value
    warnings.warn(f"{old} is deprecated; use {new}", DeprecationWarning, stacklevel=2)
    if value not in (default, old_value):  # the error names the old name already: one line, as every usage error
        raise typer.BadParameter(f"give {new} only ({old} is its deprecated name)", param_hint=new)
    typer.echo(f"snac-gym: warning: {old} is deprecated; use {new}", err=True)
    return old_value


def option_message(message: str, fields: dict[str, str]) -> str:
    """``message`` with the field it starts with (``field must ...``, ``field (--option) must ...``) named by
    the option the user typed: ``clear_timeout must be ...`` is ``--recovery-timeout must be ...``."""
    for field, option in fields.items():
        for prefix in (f"{field} ({option}) ", f"{field} "):
            if message.startswith(prefix):
                return f"{option} {message[len(prefix) :]}"
    return message


def path_parser(option: str, names: str, exists: bool = False) -> Callable[[str | Path], Path]:
    """The ``parser`` of a path option (or argument): its text as a :class:`~pathlib.Path`, an empty or blank text
    refused naming ``option``. ``Path("")`` is the current folder, so an unset shell variable (``--out "$OUT"``)
    would otherwise write there without a word. ``names`` is what the path must name: ``"a folder"``, ``"a file"``;
    ``exists``: refuse a path that does not exist.
    """

    def parse(value: str | Path) -> Path:
        if isinstance(value, Path):  # the option's default, not typed
            return value
        if not value.strip():
            raise typer.BadParameter(f"must name {names}, got an empty string", param_hint=option)
        if exists and not os.path.lexists(value):
            raise typer.BadParameter(f"path {value!r} does not exist", param_hint=option)
        return Path(value)

    return parse


def path_option(default: Any, option: str, names: str, help: str) -> Any:  # noqa: A002 - typer's own name
    """A path option whose empty value is refused (:func:`path_parser`), shown as ``<path>`` as typer shows a path."""
    return typer.Option(default, option, parser=path_parser(option, names), metavar="<path>", help=help)


def check_task(task: str) -> None:
    """Refuse a ``--task`` that names no registered task."""
    if task not in task_names():
        raise typer.BadParameter(f"must be one of {sorted(task_names())}", param_hint="--task")


def check_engine(engine: str) -> None:
    """Refuse an ``--engine`` that names no arm model (:data:`~snac_gym.physics.PHYSICS`)."""
    if engine not in PHYSICS:
        raise typer.BadParameter(f"must be one of {list(PHYSICS)}, got {engine!r}", param_hint="--engine")


def check_solver(solver: str) -> None:
    """Refuse a ``--pybullet-solver`` that names no solver (:data:`~snac_gym.physics.base.PYBULLET_SOLVERS`)."""
    if solver not in PYBULLET_SOLVERS:
        raise typer.BadParameter(
            f"must be one of {list(PYBULLET_SOLVERS)}, got {solver!r}", param_hint="--pybullet-solver"
        )


def check_robot(robot: str) -> None:
    """Refuse a ``--robot`` that names no registered robot (before the command's imports)."""
    if robot not in robot_names():
        choices = sorted(robot_names())
        raise typer.BadParameter(f"unknown robot {robot!r}; choose one of {choices}", param_hint="--robot")


def check_ur_arm(robot: str) -> None:
    """Refuse a ``--robot`` of ``real`` or ``emulate-ur`` that is not a UR arm."""
    if robot not in UR_MODELS:
        raise typer.BadParameter(f"{robot!r} is not a UR model; choose one of {UR_ARMS}", param_hint="--robot")


def check_controller(controller: str) -> None:
    """Refuse a ``--controller`` that names no registered policy (before any env is built for it)."""
    if controller not in available_policies():
        raise typer.BadParameter(
            f"unknown policy {controller!r}; available: {', '.join(available_policies())}", param_hint="--controller"
        )


#: The stop-signal guard :func:`snac_gym.apps.cli.main` holds for the whole command (``None`` where the app is called
#: without it, as by click's test runner: then only Ctrl-C interrupts, as Python's default).
main_guard: SignalGuard | None = None


#: Whether the command said it was interrupted (:func:`interrupted`), so that ``main`` does not say it again.
reported: list[str] = []


def interrupted(exc: BaseException, kept: str, during: str = "") -> typer.Exit:
    """Say in one line which signal ended the command (and ``during`` what) and what it kept; return the exit to raise
    (128 + n)."""
    name = (main_guard or SignalGuard()).signal_name(exc)
    reported.append(name)
    typer.echo(f"interrupted by {name}{' ' + during if during else ''}: {kept}", err=True)
    return typer.Exit(code=exit_code(name))
