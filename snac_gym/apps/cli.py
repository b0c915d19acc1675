"""The ``snac-gym`` command: a thin face over importable functions.

Each subcommand parses its options and calls a function that can be used from Python as well; the
subcommands live in :mod:`snac_gym.apps.commands`, one module per group, and are assembled here.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, cast

import typer

from snac_gym import __version__
from snac_gym.apps.commands import common
from snac_gym.apps.commands.evaluate import evaluate
from snac_gym.apps.commands.real import emulate_ur, real
from snac_gym.apps.commands.simulation import bench, demo, plot
from snac_gym.apps.commands.train import train_ppo_command
from snac_gym.common import startup
from snac_gym.common._signals import STOP_SIGNALS, SignalGuard, exit_code

if TYPE_CHECKING:
    from click import ClickException

__all__ = ["app", "bench", "demo", "emulate_ur", "evaluate", "main", "plot", "real", "root", "train_ppo_command"]

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


# In the order the help lists them, a newcomer's order: the paper's results first, the real arm last. Each with a
# whole sentence for that list (click cuts a docstring's first line at the column's width, mid-sentence).
app.command(short_help="Table I: each controller's trajectory cost at equal effort.")(evaluate)
app.command(short_help="One reach or track episode (Figure 3): figures, log, metrics.")(demo)
app.command(short_help="A demo's or a real run's figures, drawn again from its log.")(plot)
app.command("train-ppo", short_help="Train the PPO baseline (stable-baselines3, the rl extra).")(train_ppo_command)
app.command(short_help="Steps per second and real-time factor of the envs.")(bench)
app.command(short_help="One episode on a real UR arm (ur_rtde), or its rehearsal.")(real)
app.command("emulate-ur", short_help="An emulated UR controller to rehearse `real` against.")(emulate_ur)


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

    The cyclic garbage collector is paused until the command's imports are done (:mod:`snac_gym.common.startup`).
    """
    startup.pause()
    guard = SignalGuard()
    common.reported.clear()
    interrupt: BaseException | None = None
    try:
        # Inside the try: a signal that comes the instant the handlers are set raises here, not before it.
        common.main_guard = guard
        guard.install(STOP_SIGNALS)  # not restored: a signal while the process exits must not kill it mid-exit
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
    except RuntimeError as exc:  # after click's Abort, a RuntimeError too
        # Python 3.11 wraps what a class attribute's __set_name__ raises (a dataclass field's, while a module is
        # imported) in a RuntimeError, so a stop signal that lands there came out as a traceback; 3.12 no longer wraps
        if not isinstance(exc.__cause__, KeyboardInterrupt):
            raise
        code, interrupt = 130, exc.__cause__
    finally:
        startup.imports_done()  # a command that ended before its imports (a usage error, --help)
        guard.defer()  # the command has ended: a later signal is only recorded
        common.main_guard = None
    if code == 130 and not common.reported:  # typer's own exit for a KeyboardInterrupt no command caught
        name = guard.signal_name(interrupt)
        typer.echo(f"interrupted by {name} while the command was starting: nothing was written", err=True)
        code = exit_code(name)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":  # pragma: no cover
    main()
