"""Long runs say where they are: plain progress lines on stderr where it is not a terminal.

``snac-gym evaluate`` runs in a subprocess with stdout and stderr on pipes, as under a log file or
CI. The other runs (``train-ppo``, whose lines come from the same :class:`ProgressLines`, and the
``--no-progress`` runs, which must write no line) run in this process: typer's CliRunner keeps
stderr apart from stdout and not a terminal either, and spares a Python start and its imports
(torch's 2 s for train-ppo).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from snac_gym.evaluation.execution.progress import Progress

from snac_gym.common.progress import ProgressLines, wants_lines

EVALUATE_LINE = re.compile(r"^evaluate: \d+/\d+ rollouts \(\d+ %\), \d+\.\d s")
TRAIN_LINE = re.compile(r"^train-ppo: reach \d+/64 timesteps \(\d+ %\), \d+\.\d s")


class _Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_lines_come_every_tenth_or_every_interval_and_at_the_end():
    clock, written = _Clock(), []
    lines = ProgressLines("evaluate:", 1000, written.append, every_fraction=0.1, every_s=10.0, clock=clock)
    for i in range(99):  # 99 rollouts in 9.9 s: neither 10 % nor 10 s
        clock.now = 0.1 * (i + 1)
        assert not lines.update(1)
    clock.now = 9.95
    assert lines.update(1, detail="reference: snac")  # 10 % done
    assert written == ["evaluate: 100/1000 rollouts (10 %), 9.9 s, reference: snac"]
    clock.now = 19.0  # 9 s later, one rollout more: not due yet
    assert not lines.update(1)
    clock.now = 20.0  # 10 s after the last line, one more: due by time
    assert lines.update(1)
    assert written[-1] == "evaluate: 102/1000 rollouts (10 %), 20.0 s, reference: snac"
    clock.now = 21.0
    assert not lines.update(0)  # nothing new done: no line, however long it was
    lines.detail = ""
    assert lines.update(898)  # the end
    assert written[-1] == "evaluate: 1000/1000 rollouts (100 %), 21.0 s"
    lines.add_total(10)
    assert not lines.update(1) and lines.update(9)  # a grown total: the new end, once
    assert len(written) == 4


def test_a_fast_run_writes_at_most_one_line_per_tenth():
    written: list[str] = []
    lines = ProgressLines("evaluate:", 10_000, written.append)
    for _ in range(10_000):
        lines.update(1)
    assert 10 <= len(written) <= 11 and written[-1].startswith("evaluate: 10000/10000 rollouts (100 %)")


def test_a_long_job_that_finishes_nothing_repeats_the_line_with_its_elapsed_time():
    clock, written = _Clock(), []
    lines = ProgressLines("evaluate:", 100, written.append, clock=clock)
    clock.now = 5.0
    assert lines.update(50, detail="matching effort: mpc")
    clock.now = 60.0  # 55 s without a line: not yet
    assert not lines.heartbeat(60.0)
    clock.now = 65.0
    assert lines.heartbeat(60.0) and not lines.heartbeat(60.0)  # then quiet again for 60 s
    assert written == ["evaluate: 50/100 rollouts (50 %), 5.0 s, matching effort: mpc",
                       "evaluate: 50/100 rollouts (50 %), 65.0 s, matching effort: mpc"]  # fmt: skip
    clock.now = 70.0
    assert not lines.update(1)  # the heartbeat counts as a line for the 10 s rule


def test_progress_repeats_its_line_while_a_job_runs_and_stops_when_closed():
    """MPC's effort search ran minutes with no line: now the line comes again after ``quiet_s``."""
    import time

    written: list[str] = []
    progress = Progress(8, enabled=True, lines=True, write=written.append, quiet_s=0.05, tick_s=0.01)
    progress.status("matching effort: mpc")
    deadline = time.monotonic() + 30.0
    while len(written) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    progress.close()
    count = len(written)
    assert count >= 2 and all(line.startswith("evaluate: 0/8 rollouts (0 %)") for line in written), written
    time.sleep(0.1)
    assert len(written) == count  # closed: no line after
    silent: list[str] = []
    Progress(8, enabled=False, lines=True, write=silent.append, quiet_s=0.0, tick_s=0.01).close()
    assert silent == []


def test_progress_writes_lines_only_where_asked():
    written: list[str] = []
    progress = Progress(8, enabled=True, lines=True, write=written.append)
    progress.status("reference: dls")
    progress.update(4)
    progress.close()
    assert written and written[0].startswith("evaluate: 4/8 rollouts (50 %)") and written[0].endswith("reference: dls")
    silent: list[str] = []
    for enabled, lines in ((False, True), (True, False)):
        progress = Progress(8, enabled=enabled, lines=lines, write=silent.append)
        progress.update(8)
        progress.close()
    assert silent == []


def test_lines_are_wanted_off_a_terminal(tmp_path):
    with open(tmp_path / "log", "w") as handle:
        assert wants_lines(handle)


def _cli(arguments: list[str], cwd: Path, in_process: bool = False) -> subprocess.CompletedProcess:
    if in_process:
        from typer.testing import CliRunner

        from snac_gym.apps.cli import app

        result = CliRunner().invoke(app, arguments)
        return subprocess.CompletedProcess(arguments, result.exit_code, result.stdout, result.stderr)
    return subprocess.run(
        [sys.executable, "-m", "snac_gym.apps.cli", *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=cwd,
        timeout=300,
    )


@pytest.mark.parametrize("progress", [True, False])
def test_evaluate_writes_progress_lines_to_stderr_off_a_terminal(tmp_path, progress):
    arguments = [
        "evaluate",
        "--out",
        str(tmp_path / "run"),
        "--samples",
        "4",
        "--horizon",
        "0.3",
        "--controllers",
        "dls,lqr",
        "--effort-reference",
        "dls",
        "--effort-samples",
        "0",
    ]
    result = _cli(arguments + ([] if progress else ["--no-progress"]), tmp_path, in_process=not progress)
    assert result.returncode == 0, result.stderr
    assert "Trajectory cost V/N" in result.stdout
    assert "rollouts" not in result.stdout  # the summary on stdout stays clean
    lines = [line for line in result.stderr.splitlines() if EVALUATE_LINE.match(line)]
    if progress:
        assert lines and lines[-1].startswith("evaluate: 16/16 rollouts (100 %)"), result.stderr
        assert len(lines) <= 11  # at most one per tenth (the run is far shorter than 10 s a line)
        # It matches effort on its own samples (no knobs read: the suite turns the calibration cache off), and says so
        # first.
        assert MATCHING.findall(result.stderr) == [("4", "the calibration cache is off", "--no-match-effort skips it")]
        assert result.stderr.index("matching equal effort first") < result.stderr.index(lines[0])
    else:
        assert lines == [] and "evaluate:" not in result.stderr


@pytest.mark.parametrize("progress", [True, False])
def test_train_ppo_writes_progress_lines_to_stderr_off_a_terminal(tmp_path, progress, tiny_ppo):
    pytest.importorskip("stable_baselines3")

    arguments = [
        "train-ppo",
        "--task",
        "reach",
        "--timesteps",
        "64",
        "--seed",
        "3",
        "--out",
        str(tmp_path / "run"),
        "--config",
        str(tiny_ppo(tmp_path)),
    ]
    result = _cli(arguments + ([] if progress else ["--no-progress"]), tmp_path, in_process=True)
    assert result.returncode == 0, result.stderr
    assert "finished: " in result.stdout and "train-ppo:" not in result.stdout
    lines = [line for line in result.stderr.splitlines() if TRAIN_LINE.match(line)]
    if progress:
        assert lines, result.stderr
        assert lines[-1].startswith("train-ppo: reach 64/64 timesteps (100 %)")
        assert any("success " in line for line in lines), lines  # after the first evaluation (32 timesteps)
    else:
        assert lines == [] and "train-ppo:" not in result.stderr


@pytest.mark.parametrize(("cached", "progress"), [(False, True), (True, True), (False, False)])
def test_a_run_that_compiles_the_kernels_says_so_before_anything_else(tmp_path, monkeypatch, capsys, cached, progress):
    """A first run (numba's cache empty or out of date) compiles the kernels before its first progress line: it says
    so first, naming why; a run that finds every kernel in the cache, or runs without progress, says nothing."""
    from snac_gym.evaluation import EvaluationConfig, run_evaluation
    from snac_gym.evaluation.runner import COMPILING

    import snac_gym.kernels.compiled as compiled

    asked: list[tuple[str, ...]] = []
    monkeypatch.setattr(compiled, "cached_on_disk", lambda modules: asked.append(modules) or cached)
    config = EvaluationConfig(out=tmp_path / "run", samples=2, tasks=("reach",), horizons={"reach": 0.2},
                              controllers=("dls",), match_effort=False, progress=progress, plots=False)  # fmt: skip
    run_evaluation(config)
    err = capsys.readouterr().err
    # the kernels this run calls: without the reference, not the reference's (they would announce a compile that
    # never comes)
    expected = tuple(m for m in compiled.EVALUATOR_KERNEL_MODULES if m not in compiled.LATE_KERNEL_MODULES)
    assert asked == ([expected] if progress else [])
    if progress and not cached:
        first = err.splitlines()[0]
        assert first == COMPILING and "numba's cache has none for this code yet" in first, err
    assert (COMPILING in err) == (progress and not cached), err


MATCHING = re.compile(r"^evaluate: matching equal effort first, on (\d+) samples a task \((.+)\); (.+)$", re.M)


def test_a_run_that_matches_effort_first_says_so_why_and_how_to_shorten_it(tmp_path):
    """A run whose knobs are neither cached nor shipped searches them on the effort set before its own samples (1000
    a task by default, whatever --samples): one line says so, on how many samples, why, and which options cut it.
    In process, beside the console script's run in the test above."""
    arguments = ["evaluate", "--samples", "4", "--horizon", "0.3", "--controllers", "dls,lqr", "--effort-reference",
                 "dls", "--effort-samples", "6"]  # fmt: skip
    result = _cli([*arguments, "--out", str(tmp_path / "larger")], tmp_path, in_process=True)
    assert result.returncode == 0, result.stderr
    shorter = "--no-match-effort skips it, --effort-samples 0 matches on the evaluated samples"
    assert MATCHING.findall(result.stderr) == [("6", "the calibration cache is off", shorter)], result.stderr
    for quiet in ("--no-progress", "--no-match-effort"):
        kept = arguments[:7] + (arguments[7:] if quiet == "--no-progress" else [])  # no effort options without a match
        other = _cli([*kept, quiet, "--out", str(tmp_path / quiet.strip("-"))], tmp_path, in_process=True)
        assert other.returncode == 0, other.stderr
        assert "matching equal effort" not in other.stderr, quiet


@pytest.mark.parametrize(
    ("recalibrate", "cache_on", "why"),
    [
        (True, True, "--recalibrate"),
        (False, False, "the calibration cache is off"),
        (False, True, "no knobs cached or shipped for these controllers at these settings"),
    ],
)
def test_the_matching_notice_names_why_no_knobs_were_read(recalibrate, cache_on, why):
    from snac_gym.evaluation.run_config import EvaluationConfig
    from snac_gym.evaluation.runner import announce_matching

    written: list[str] = []
    config = EvaluationConfig(out=Path("unused"), recalibrate=recalibrate)
    announce_matching(written.append, config, {"reach": [0] * 3}, {"reach": [0] * 3}, cache_on)  # type: ignore[list-item]
    line = f"evaluate: matching equal effort first, on 3 samples a task ({why}); --no-match-effort skips it\n"
    assert written == [line]


def test_a_run_at_the_shipped_knobs_matches_nothing_and_says_nothing_of_it(tmp_path, monkeypatch):
    """The default controllers at the default settings read the shipped knobs: no notice, and no match."""
    monkeypatch.setenv("SNAC_GYM_CALIBRATION_CACHE", "1")
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "cache"))  # empty: the shipped knobs, not a cached match
    arguments = ["evaluate", "--samples", "2", "--controllers", "snac,dls", "--out", str(tmp_path / "run")]
    result = _cli(arguments, tmp_path, in_process=True)
    assert result.returncode == 0, result.stderr
    assert "matching equal effort" not in result.stderr and "matching effort" not in result.stderr, result.stderr
