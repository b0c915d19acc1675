"""``snac-gym evaluate``: unbounded inputs are refused before they hang or exhaust memory, and an
option that another makes meaningless is refused instead of being silently ignored."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from snac_gym.evaluation import EvaluationConfig
from snac_gym.evaluation.run_config import BYTES_PER_SAMPLE, max_samples
from snac_gym.evaluation.samples import MAX_SAMPLES_FILE_BYTES, SampleFileError, check_samples_file, read_samples_csv
from typer.testing import CliRunner

from snac_gym.apps.cli import app
from snac_gym.model.kinematics import Kinematics


def _evaluate(*arguments: str):
    return CliRunner().invoke(app, ["evaluate", "--no-progress", "--no-plots", *arguments])


def _one_line_error(result, message: str) -> None:
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.output, result.output
    assert message in lines[0], lines[0]


@pytest.fixture
def samples_csv(tmp_path) -> Path:
    path = tmp_path / "samples.csv"
    exported = _evaluate("--task", "reach", "--samples", "2", "--export-samples", str(path), "--export-only")
    assert exported.exit_code == 0, exported.output
    return path


@pytest.mark.parametrize(
    ("source", "message"),
    [
        ("/dev/zero", "must be a regular CSV file, not a device, pipe or socket"),
        ("/dev/urandom", "must be a regular CSV file, not a device, pipe or socket"),
        ("fifo", "must be a regular CSV file, not a device, pipe or socket"),
        ("folder", "must be a regular CSV file, not a folder"),
        ("missing.csv", "no such samples file"),
        ("huge.csv", f"above the samples file limit of {MAX_SAMPLES_FILE_BYTES} bytes"),
    ],
)
def test_a_samples_file_that_never_ends_or_is_too_large_is_refused_at_once(tmp_path, source, message):
    if source == "fifo":
        path = tmp_path / "fifo"
        os.mkfifo(path)  # no writer: opening it would block for ever
    elif source == "folder":
        path = tmp_path
    elif source == "huge.csv":
        path = tmp_path / source
        with path.open("wb") as handle:  # sparse: no disk used
            handle.truncate(MAX_SAMPLES_FILE_BYTES + 1)
    else:
        path = Path(source) if source.startswith("/") else tmp_path / source
    _one_line_error(_evaluate("--out", str(tmp_path / "run"), "--samples-file", str(path)), message)
    with pytest.raises(SampleFileError, match=message.replace("(", r"\(")):  # the library path too
        read_samples_csv(path, Kinematics("ur10"))
    assert not (tmp_path / "run" / "run.json").exists()


def test_samples_beyond_what_the_memory_holds_are_refused(tmp_path):
    bound = max_samples()
    memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    assert bound == memory // 2 // BYTES_PER_SAMPLE  # the stated derivation
    _one_line_error(
        _evaluate("--out", str(tmp_path / "run"), "--samples", "100000000000"),
        f"samples must be between 1 and {bound} per task (half of this machine's memory at 16 kB a sample)",
    )
    with pytest.raises(ValueError, match="samples must be between 1 and"):
        EvaluationConfig(out=tmp_path, samples=bound + 1).validate()
    EvaluationConfig(out=tmp_path, samples=bound).validate()  # the bound itself is accepted


def test_a_regular_small_samples_file_passes_the_check(samples_csv):
    check_samples_file(samples_csv)


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--cuboid", "nan,0,0,1,1,1"], "--cuboid 'nan,0,0,1,1,1': every coordinate must be a finite number"),
        (["--cuboid", "0,0,0,inf,1,1"], "every coordinate must be a finite number"),
        (["--effort-reference", "nosuch"], "--effort-reference 'nosuch' names no registered controller"),
        (["--effort-reference", "dls", "--controllers", "snac,rnn"], "'dls' is not among --controllers snac,rnn"),
        (["--effort-reference", "dls", "--no-match-effort"], "--effort-reference has no effect with --no-match-effort"),
        (
            ["--effort-reference", "dls", "--effort-target", "1"],
            "--effort-reference has no effect with --effort-target",
        ),
        (["--sweep-points", "5"], "--sweep-points has no effect without --sweep"),
        (["--sweep-span", "3"], "--sweep-span has no effect without --sweep"),
        (["--effort-samples", "500", "--no-match-effort"], "--effort-samples has no effect with --no-match-effort"),
        (["--task", "reach", "--horizon", "track=3"], "the run does not evaluate 'track' (--task)"),
        (["--horizon", "reach=3", "--horizon", "reach=1"], "a horizon for reach is given twice"),
        (["--horizon", "3", "--horizon", "track=1"], "a horizon for track is given twice"),
    ],
)
def test_meaningless_or_ignored_options_are_refused_naming_the_option(tmp_path, arguments, message):
    _one_line_error(_evaluate("--out", str(tmp_path / "run"), *arguments), message)
    assert not (tmp_path / "run").exists()  # refused before the output folder is made


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--samples", "5"], "--samples has no effect with --samples-file"),
        (["--cuboid", "-1,-1,0,0,0,1"], "--cuboid has no effect with --samples-file"),
        (["--effort-samples", "500"], "--effort-samples has no effect with --samples-file"),
        (["--export-samples", "SAME"], "is the --samples-file it reads"),
    ],
)
def test_options_that_a_samples_file_overrides_are_refused(tmp_path, samples_csv, extra, message):
    extra = [str(samples_csv) if value == "SAME" else value for value in extra]
    before = samples_csv.read_bytes()
    _one_line_error(_evaluate("--out", str(tmp_path / "run"), "--samples-file", str(samples_csv), *extra), message)
    assert samples_csv.read_bytes() == before


def test_an_unregistered_effort_reference_is_refused_by_the_library_too(tmp_path):
    with pytest.raises(ValueError, match="effort_reference 'nosuch' names no registered controller"):
        EvaluationConfig(out=tmp_path, effort_reference="nosuch").validate()
    EvaluationConfig(out=tmp_path, effort_reference="nosuch", match_effort=False).validate()  # unused: allowed
