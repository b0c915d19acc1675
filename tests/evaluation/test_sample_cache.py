"""The drawn samples cached by what they are drawn from (evaluation/sample_cache.py): read back bit for bit, drawn
only where no chunk holds them, keyed by every input and the code, and never handed back damaged."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from snac_gym.evaluation import runner, sample_cache
from snac_gym.evaluation.cache_entry import checksum
from snac_gym.evaluation.execution.executors import SerialExecutor
from snac_gym.evaluation.run_config import EvaluationConfig
from snac_gym.evaluation.samples import generate_samples

from snac_gym.model.kinematics import Kinematics
from snac_gym.sampling import SampleSpace


@pytest.fixture
def cache_on(tmp_path, monkeypatch) -> Path:
    """The sample cache on, in an empty folder (the suite turns it off: conftest.py); the folder of its entries."""
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv(sample_cache.SWITCH_ENV, raising=False)
    return tmp_path / "cache" / "samples"


class CountingExecutor(SerialExecutor):
    """The in-process executor, counting the samples it draws."""

    def __init__(self) -> None:
        self.drawn: list[tuple[str, int, int]] = []

    def run(self, function, items, priority=0):
        self.drawn += [(task, indices[0], indices[-1] + 1) for _, _, _, task, indices in items]
        return super().run(function, items, priority)


def _config(**changes) -> EvaluationConfig:
    return EvaluationConfig(out=Path("unused"), **changes)


def _draw(config: EvaluationConfig, first: int, end: int, executor=None):
    kinematics, space = runner._checked_setting(config)
    executor = executor if executor is not None else CountingExecutor()
    return runner._draw(config, kinematics, space, executor, first, end), executor


def _same_value(a, b) -> bool:
    if dataclasses.is_dataclass(a):
        return type(a) is type(b) and all(
            _same_value(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a)
        )
    return np.asarray(a).tobytes() == np.asarray(b).tobytes()


def _same(a, b) -> bool:
    """Whether two samples are the same bit for bit: task, index, θ₀ and every field of the reference (a pose's
    position reference too)."""
    return (a.task, a.index) == (b.task, b.index) and _same_value(a.q0, b.q0) and _same_value(a.reference, b.reference)


def test_a_second_draw_reads_every_sample_back_bit_for_bit(cache_on):
    config = _config()
    first, drew = _draw(config, 0, 30)
    again, read = _draw(config, 0, 30)
    assert drew.drawn and read.drawn == []  # the second draw drew nothing
    kinematics = Kinematics(config.robot)
    for task in config.tasks:
        fresh = generate_samples(kinematics, SampleSpace.for_robot(kinematics), config.seed, task, range(30))
        assert len(again[task]) == 30
        assert all(_same(a, b) for a, b in zip(again[task], fresh, strict=True))
        assert all(_same(a, b) for a, b in zip(first[task], fresh, strict=True))


def test_runs_of_other_sizes_share_the_aligned_chunks(cache_on):
    config = _config(tasks=("reach",))
    _draw(config, 0, 60)  # chunks 0-25, 25-50, 50-60
    _, executor = _draw(config, 0, 80)
    assert executor.drawn == [("reach", 50, 75), ("reach", 75, 80)]  # the partial chunk 50-60 is an entry of its own
    _, executor = _draw(config, 30, 75)  # an effort set after 30 evaluated samples: 30-50 is a chunk of its own
    assert executor.drawn == [("reach", 30, 50)]


@pytest.mark.parametrize(
    "change",
    [{"seed": 1}, {"space": SampleSpace(min_singular_value=0.06)}, {"robot": "ur5"}, "code"],
    ids=["seed", "space", "robot", "code"],
)
def test_any_other_input_is_drawn_anew(cache_on, monkeypatch, change):
    config = _config(tasks=("track",))
    _draw(config, 0, 5)
    if change == "code":  # an edited sampler, task or kinematics: another fingerprint
        monkeypatch.setattr(sample_cache, "code_fingerprint", lambda module: "edited")
    else:
        config = dataclasses.replace(config, **change)
    samples, executor = _draw(config, 0, 5)
    assert executor.drawn == [("track", 0, 5)]
    kinematics = Kinematics(config.robot)
    space = config.space if config.space is not None else SampleSpace.for_robot(kinematics)
    fresh = generate_samples(kinematics, space, config.seed, "track", range(5))
    assert all(_same(a, b) for a, b in zip(samples["track"], fresh, strict=True))


def test_the_key_follows_the_code_that_draws():
    """The modules whose edits must miss the cache are in the fingerprint's import graph."""
    from snac_gym.evaluation.code_graph import module_closure

    modules = module_closure((*sample_cache.ROOTS, "snac_gym.tasks.track"))
    for module in ("snac_gym.sampling", "snac_gym.tasks.track", "snac_gym.references", "snac_gym.model.kinematics",
                   "snac_gym.model.position_kinematics", "snac_gym.model.robots"):  # fmt: skip
        assert module in modules


def test_a_task_of_another_package_is_never_cached(cache_on, monkeypatch):
    from snac_gym.tasks import get_task

    task = get_task("track")
    outside = type("OutsideTrack", (type(task),), {"__module__": "mypackage.tasks"})
    monkeypatch.setattr(sample_cache, "get_task", lambda name: outside() if name == "track" else get_task(name))
    assert not sample_cache.cacheable("track") and sample_cache.cacheable("reach")
    monkeypatch.setattr(get_task("reach"), "semi_axes", (0.1, 0.2), raising=False)  # a built-in task given state
    assert not sample_cache.cacheable("reach")
    monkeypatch.delattr(get_task("reach"), "semi_axes")
    config = _config()
    _draw(config, 0, 3)
    _, executor = _draw(config, 0, 3)
    assert executor.drawn == [("track", 0, 3)]


def _entries(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.json"))


def _rewrite(path: Path, edit) -> None:
    """Apply ``edit`` to the entry's samples and store it with a valid checksum (a forged, not a torn, entry)."""
    entry = json.loads(path.read_text())
    edit(entry["payload"])
    entry["sha256"] = checksum(entry["key"], entry["payload"])
    path.write_text(json.dumps(entry))


@pytest.mark.parametrize(
    "damage",
    ["edited", "forged other index", "forged out of limits", "forged unreadable", "truncated", "another key"],
)
def test_a_damaged_entry_is_named_and_drawn_again(cache_on, capfd, damage):
    config = _config(tasks=("track",))
    first, _ = _draw(config, 0, 4)
    (path,) = _entries(cache_on)
    if damage == "edited":  # a digit changed by hand: the checksum no longer holds
        path.write_text(path.read_text().replace('"q0_0": "', '"q0_0": "1', 1))
    elif damage == "forged other index":
        _rewrite(path, lambda rows: rows[1].update(sample="7"))
    elif damage == "forged out of limits":
        _rewrite(path, lambda rows: rows[0].update(q0_0="99.0"))
    elif damage == "forged unreadable":
        _rewrite(path, lambda rows: rows[2].update(semi_axis_0="wide"))
    elif damage == "truncated":
        _rewrite(path, lambda rows: rows.pop())
    else:  # another chunk's entry copied under this chunk's name
        _draw(config, 4, 8)
        (other,) = [entry for entry in _entries(cache_on) if entry != path]
        path.write_text(other.read_text())
    capfd.readouterr()
    again, executor = _draw(config, 0, 4)
    err = capfd.readouterr().err
    assert executor.drawn == [("track", 0, 4)]
    assert f"warning: the sample cache: ignored the damaged entry {path}" in err and "computing it again" in err
    assert all(_same(a, b) for a, b in zip(again["track"], first["track"], strict=True))
    _, executor = _draw(config, 0, 4)  # stored whole again
    assert executor.drawn == []


def test_an_unwritable_folder_is_named_once_and_the_run_goes_on(cache_on, capfd):
    cache_on.parent.mkdir(parents=True)
    cache_on.write_text("a file where the folder goes")
    samples, executor = _draw(_config(), 0, 30)
    err = capfd.readouterr().err
    assert [len(samples[task]) for task in ("reach", "track")] == [30, 30]
    assert err.count("warning: the sample cache: cannot write to") == 1, err


def test_turned_off_it_neither_reads_nor_writes(cache_on, monkeypatch):
    monkeypatch.setenv(sample_cache.SWITCH_ENV, "0")
    _draw(_config(), 0, 3)
    assert not cache_on.exists()


def test_a_run_on_cached_samples_gives_the_same_rows(tmp_path, cache_on, monkeypatch):
    """End to end: a second run draws nothing and its rows are the first run's, bit for bit."""
    options = dict(samples=3, controllers=("dls",), match_effort=False, workers=1, progress=False, plots=False,
                   horizons={"reach": 0.4, "track": 0.4})  # fmt: skip
    runner.run_evaluation(EvaluationConfig(out=tmp_path / "first", **options))
    monkeypatch.setattr(runner, "generate_samples", lambda *args: pytest.fail("drew a sample"))
    runner.run_evaluation(EvaluationConfig(out=tmp_path / "second", **options))
    first, second = (pd.read_parquet(tmp_path / name / "results.parquet") for name in ("first", "second"))
    pd.testing.assert_frame_equal(first, second, check_exact=True)
    assert (tmp_path / "first" / "samples.csv").read_bytes() == (tmp_path / "second" / "samples.csv").read_bytes()


@pytest.mark.usefixtures("pose_tasks")
def test_the_pose_tasks_samples_read_back_bit_for_bit(cache_on):
    config = _config(tasks=("pose-reach", "pose-track"))
    _draw(config, 0, 4)
    again, executor = _draw(config, 0, 4)
    assert executor.drawn == []
    kinematics = Kinematics(config.robot)
    for task in config.tasks:
        fresh = generate_samples(kinematics, SampleSpace.for_robot(kinematics), config.seed, task, range(4))
        assert all(_same(a, b) for a, b in zip(again[task], fresh, strict=True))
