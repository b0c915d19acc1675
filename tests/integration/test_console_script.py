"""Usage errors through the installed ``snac-gym`` console script: exit 2 and one line, never a traceback.

The other CLI tests drive the commands through typer's in-process runner, which runs click's own
standalone handling and never goes through :func:`snac_gym.apps.cli.main`. Here the script that pip
installed runs in a subprocess, so ``main()``'s handling is what is tested: it must catch the click
exceptions typer really raises (typer 0.29 and later raise those of their own copy of click,
``typer._click``, not the standalone click's). Each command below fails while its options are
parsed or checked, before it writes anything; they run two at a time, on a module fixture.
"""

from __future__ import annotations

import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

SCRIPT = Path(sys.executable).parent / "snac-gym"

#: (arguments, the option the one line must name). ``{out}`` is a folder under the test's tmp_path.
USAGE_ERRORS = [
    (["evaluate", "--samples", "0"], "--samples"),
    (["evaluate", "--chunk-size", "0"], "--chunk-size"),
    (["evaluate", "--bogus-option", "1"], "--bogus-option"),
    (["demo", "--task", "orbit"], "--task"),  # _check_task: a typer.BadParameter in the command body
    (["demo", "--steps", "0"], "--steps"),
    (["demo", "--engine", "bullet"], "--engine"),
    (["demo", "--pybullet-solver", "lcp"], "--pybullet-solver"),
    (["demo", "--steps", "1", "--duration", "1"], "--steps"),  # raised in the body, after the demo's imports
    (["demo", "--bogus-option", "1"], "--bogus-option"),
    (["demo", "--out", ""], "--out"),  # Path("") would be the current folder
    (["plot", "{out}/reach_snac_log.parquet"], "'LOG'"),  # no such log
    (["plot", "--bogus-option", "1"], "--bogus-option"),
    (["plot", ""], "'LOG'"),
    (["real", "--robot", "panda"], "--robot"),  # _check_ur_arm, in the body
    (["real", "--rt-priority", "200"], "--rt-priority"),
    (["real", "--backend", "rtde", "--connection", "sim"], "--connection"),  # the deprecated name's clash
    (["real", "--bogus-option", "1"], "--bogus-option"),
    (["bench", "--steps", "1e3"], "--steps"),
    (["bench", "--act-calls", "many"], "--act-calls"),
    (["bench", "--bogus-option", "1"], "--bogus-option"),
    (["train-ppo", "--task", "orbit", "--out", "{out}"], "--task"),
    (["train-ppo", "--task", "orbit"], "--out"),  # the required --out is missing
    (["train-ppo", "--n-envs", "0"], "--n-envs"),
    (["train-ppo", "--bogus-option", "1"], "--bogus-option"),
    (["emulate-ur", "--rt-priority", "200"], "--rt-priority"),
    (["emulate-ur", "--robot", "panda"], "--robot"),
    (["emulate-ur", "--port-base", "http"], "--port-base"),
    (["emulate-ur", "--bogus-option", "1"], "--bogus-option"),
    (["--bogus-option"], "--bogus-option"),  # the root command's own options
]

#: A deprecated option's name at the shell, where Python hides its ``DeprecationWarning``; the run then refused
#: for a controller no one registered, before it writes anything.
DEPRECATED = "\0".join(["evaluate", "--backend", "kinematic", "--controllers", "nosuch", "--out", "{out}"])

#: ``python -m snac_gym demo --steps 0``: the same ``main()`` through the package's ``__main__``.
MODULE = "module:" + "\0".join(["demo", "--steps", "0"])

#: ``main()`` with the app swapped for one raising ``sys.argv[1]``'s exception: as an older typer, which
#: raises the standalone click's classes, would; and typer's own Abort (end of input at a prompt).
DRIVER = """
import sys
import click
import typer
from snac_gym.apps import cli

raised = {
    "click-usage": lambda: click.BadParameter("must be positive", param_hint="'--knob'"),
    "click-abort": lambda: click.exceptions.Abort(),
    "typer-abort": lambda: typer.Abort(),
}[sys.argv[1]]


def app(**kwargs):
    raise raised()


cli.app = app
cli.main()
"""

DRIVEN = {"click-usage": (2, "snac-gym: error: Invalid value for '--knob': must be positive"),
          "click-abort": (1, "Aborted!"), "typer-abort": (1, "Aborted!")}  # fmt: skip


def _command_line(key: str, out: Path) -> list[str]:
    if key.startswith("driver:"):
        return [sys.executable, "-c", DRIVER, key.removeprefix("driver:")]
    if key.startswith("module:"):  # python -m snac_gym, for an environment whose scripts are not on PATH
        return [sys.executable, "-m", "snac_gym", *key.removeprefix("module:").split("\0")]
    return [str(SCRIPT), *(arg.format(out=out) for arg in key.split("\0"))]


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory, once) -> dict[str, subprocess.CompletedProcess]:
    """Every command of this file, run once per test session, two at a time (the script's start-up is ~0.4 s
    each): once, not once per pytest-xdist worker that runs one of these tests (``once``, tests/conftest.py)."""
    if not SCRIPT.exists():
        pytest.skip(f"no installed console script at {SCRIPT} (install the package: pip install -e .)")
    keys = (
        ["\0".join(args) for args, _ in USAGE_ERRORS] + [f"driver:{name}" for name in DRIVEN] + ["", MODULE, DEPRECATED]
    )

    def run_all() -> dict[str, list]:
        cwd = tmp_path_factory.mktemp("console")  # nothing may be written, but never into the checkout
        out = cwd / "train"
        env = {key: value for key, value in os.environ.items() if key != "PYTHONWARNINGS"}
        env["COLUMNS"] = "200"

        def run(key: str) -> list:
            command = _command_line(key, out) if key else [str(SCRIPT)]
            done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=120)
            return [done.args, done.returncode, done.stdout, done.stderr]

        with ThreadPoolExecutor(max_workers=2) as pool:
            results = dict(zip(keys, pool.map(run, keys)))
        assert not out.exists(), "a refused command wrote its output folder"
        return results

    results = once("console-script-outcomes", run_all)
    return {key: subprocess.CompletedProcess(*results[key]) for key in keys}


@pytest.mark.parametrize(("args", "option"), USAGE_ERRORS, ids=[" ".join(args) for args, _ in USAGE_ERRORS])
def test_a_usage_error_is_one_line_and_exit_2(outcomes, args, option):
    done = outcomes["\0".join(args)]
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode == 2, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].strip(), done.stderr  # one line, not click's usage block
    line = lines[0]
    command = args[0] if not args[0].startswith("-") else ""
    assert line.startswith(f"snac-gym{' ' + command if command else ''}: error: "), line
    assert option in line, line
    assert line.endswith(f"(see 'snac-gym{' ' + command if command else ''} --help')"), line
    assert done.stdout == "", done.stdout


@pytest.mark.parametrize("name", sorted(DRIVEN))
def test_main_catches_the_standalone_clicks_exceptions_and_typers_abort(outcomes, name):
    done = outcomes[f"driver:{name}"]
    code, line = DRIVEN[name]
    assert "Traceback" not in done.stderr, done.stderr
    assert (done.returncode, done.stderr.splitlines()) == (code, [line])


def test_python_m_snac_gym_is_the_command_with_its_own_name_in_the_line(outcomes):
    done = outcomes[MODULE]
    assert (done.returncode, done.stdout) == (2, ""), done.stderr
    assert done.stderr.startswith("python -m snac_gym demo: error: Invalid value for '--steps'"), done.stderr
    assert len(done.stderr.splitlines()) == 1, done.stderr


def test_a_deprecated_option_says_so_on_stderr_before_the_run_goes_on(outcomes):
    done = outcomes[DEPRECATED]
    assert "Traceback" not in done.stderr, done.stderr
    lines = done.stderr.splitlines()
    assert lines[0] == "snac-gym: warning: --backend is deprecated; use --engine", done.stderr
    # the run went on with the old name's value, to the next check
    assert done.returncode == 2 and "unknown controller 'nosuch'" in lines[-1], done.stderr


def test_no_command_prints_the_help(outcomes):
    done = outcomes[""]
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode == 2  # click's exit for no_args_is_help, as in its standalone mode
    text = done.stdout + done.stderr
    assert "Usage: snac-gym" in text
    # each command on one line of its own, a whole sentence (click cuts a docstring mid-sentence with "..."), the
    # paper's results first
    listed = text.split("Commands:\n", 1)[1].splitlines()
    names = [line.split()[0] for line in listed if line.strip()]
    assert names == ["evaluate", "demo", "plot", "train-ppo", "bench", "real", "emulate-ur"], listed
    assert all(line.rstrip().endswith(".") and "..." not in line for line in listed if line.strip()), listed


def test_the_exception_classes_of_both_clicks_are_caught():
    import typer

    from snac_gym.apps.cli import _click_aborts, _click_errors

    errors, aborts = _click_errors(), _click_aborts()
    assert issubclass(typer.BadParameter, errors)  # what the commands' own checks raise
    assert typer.Abort in aborts
    try:
        import click
    except ImportError:
        return
    assert click.ClickException in errors and click.exceptions.Abort in aborts
