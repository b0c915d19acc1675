"""Every file the commands write is written whole (snac_gym/common/outputs.py): a failed write leaves the old file
or none
under the final name, never a truncated one, and the error names the file and the free space."""

from __future__ import annotations

import errno
import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation

from snac_gym.common.outputs import OutputWriteError, removed_if_left_empty, write_text_whole, written_whole


def test_a_failed_write_leaves_the_old_file_and_names_the_file_and_the_free_space(tmp_path):
    path = tmp_path / "summary.md"
    write_text_whole(path, "old")
    with pytest.raises(OutputWriteError, match=rf"could not write {path}: No space left on device \(.* free\)"):
        with written_whole(path) as partial:
            partial.write_text("half of the new")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert path.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.md"]  # no temporary left behind


def test_a_full_disk_while_the_results_are_written_leaves_no_truncated_results_file(tmp_path, monkeypatch):
    written = pd.DataFrame.to_parquet

    def full_disk(self, path, *args, **kwargs):
        if "results" in Path(path).name:
            written(self.iloc[:1], path, *args, **kwargs)  # part of it is on disk, then the disk is full
            raise OSError(errno.ENOSPC, "No space left on device")
        return written(self, path, *args, **kwargs)

    monkeypatch.setattr(pd.DataFrame, "to_parquet", full_disk)
    config = EvaluationConfig(out=tmp_path / "run", samples=2, controllers=("dls",), tasks=("reach",),
                              horizons={"reach": 0.2}, match_effort=False, progress=False, plots=False)  # fmt: skip
    with pytest.raises(OutputWriteError, match=r"results\.parquet: No space left on device \(.* free\)"):
        run_evaluation(config)
    assert not (tmp_path / "run" / "results.parquet").exists()
    assert not list((tmp_path / "run").glob("*.partial*"))


def _file_size_limit(limit: int):
    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


def test_the_command_on_a_full_disk_says_which_file_in_one_line(tmp_path):
    """``ulimit -f`` below the first file the run writes, through the command: one line naming that file."""
    out = tmp_path / "run"
    command = [sys.executable, "-m", "snac_gym.apps.cli", "evaluate", "--samples", "2", "--controllers", "dls",
               "--task", "reach", "--horizon", "0.2", "--no-match-effort", "--no-progress", "--no-plots",
               "--out", str(out)]  # fmt: skip
    # No bytecode written under the limit: CPython writes a .pyc with one unchecked write(), which the limit
    # would cut short, leaving a truncated .pyc that breaks every later import of that module.
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    done = subprocess.run(
        command, capture_output=True, text=True, timeout=120, preexec_fn=_file_size_limit(64), env=env
    )
    assert done.returncode != 0 and "Traceback" not in done.stderr, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "could not write" in lines[0] and str(out) in lines[0] and "free" in lines[0], lines
    for path in out.rglob("*"):  # whatever is under its final name is whole: nothing past the limit is there
        assert not path.is_file() or path.stat().st_size < 64 or path.name == ".lock", path


def test_a_run_that_fails_before_writing_removes_the_folders_it_made_and_nothing_else(tmp_path):
    (tmp_path / "there").mkdir()
    for out in (tmp_path / "a" / "b" / "run", tmp_path / "there" / "run", tmp_path / "there"):
        with pytest.raises(ConnectionError):
            with removed_if_left_empty(out):
                assert out.is_dir()  # made before the work, as usable_out_folder makes it
                raise ConnectionError("nothing answers")
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["there"]  # the folder that was there stays


def test_a_run_that_wrote_something_or_succeeded_keeps_its_folder(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with removed_if_left_empty(tmp_path / "a" / "run"):
            (tmp_path / "a" / "run" / "log.parquet").write_bytes(b"rows")
            raise KeyboardInterrupt
    assert (tmp_path / "a" / "run" / "log.parquet").read_bytes() == b"rows"
    with removed_if_left_empty(tmp_path / "b" / "run"):
        pass
    assert (tmp_path / "b" / "run").is_dir()
    with removed_if_left_empty(None):  # no folder asked for: nothing made
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b"]
