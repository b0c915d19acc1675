"""``--resume`` of a run that read its knobs (the calibration cache's or the shipped ones) instead of matching them:
it goes on at the knobs it kept in its calibration.json, finished or cut short, whatever the caches hold now."""

from __future__ import annotations

import json
import shutil

import pandas as pd
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation import runner as runner_module
from snac_gym.evaluation.effort import cache
from snac_gym.evaluation.store import RunDirectoryError

#: At the defaults the knobs of dls and lqr (matched to SNAC's effort) ship with the package: with an empty cache, a
#: run reads them.
SHIPPED = {"controllers": ("snac", "dls", "lqr"), "samples": 3, "progress": False, "plots": False}


@pytest.fixture(scope="module")
def finished_once(tmp_path_factory):
    """One run at the shipped knobs for the module (each test edits a copy of it)."""
    folder = tmp_path_factory.mktemp("resume-knobs")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(cache.SWITCH_ENV, "1")  # the tests run with the calibration cache off (tests/conftest.py)
        patch.setenv("SNAC_GYM_CACHE_DIR", str(folder / "cache"))
        rows = run_evaluation(EvaluationConfig(out=folder / "run", **SHIPPED))
    return folder, rows


@pytest.fixture
def finished(finished_once, tmp_path, monkeypatch):
    """The module's run and its calibration cache, copied to this test's folder, the cache on and there."""
    folder, rows = finished_once
    for name in ("run", "cache"):
        shutil.copytree(folder / name, tmp_path / name)
    monkeypatch.setenv(cache.SWITCH_ENV, "1")
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "run", rows.copy()


def _resume(out):
    return run_evaluation(EvaluationConfig(out=out, resume=True, **SHIPPED))


def _no_cache_read(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("a resumed run read the calibration cache or the shipped knobs")

    monkeypatch.setattr(runner_module, "read_records", refuse)
    monkeypatch.setattr(runner_module, "read_shipped", refuse)


def test_a_run_at_the_shipped_knobs_resumes_finished_or_cut_short_to_the_same_rows(finished, monkeypatch):
    out, rows = finished
    kept = json.loads((out / "calibration.json").read_text())[runner_module.KNOBS_READ_KEY]
    assert {(r["task"], r["controller"]) for r in kept["records"]} == {
        (task, name) for task in ("reach", "track") for name in ("snac", "dls", "lqr")
    }
    assert "shipped" in kept["stamp"]["origin"]
    _no_cache_read(monkeypatch)
    # Finished: the resume goes straight to its reports (it refused: "belongs to other samples", as it matched).
    pd.testing.assert_frame_equal(_resume(out), rows, check_exact=True)
    # Cut short: one job's part gone, as after an interrupt; the resume runs that job alone at the kept knobs.
    (part,) = (out / "parts").glob("track__lqr__*.parquet")
    others = {p: p.stat().st_mtime_ns for p in (out / "parts").glob("*.parquet") if p != part}
    part.unlink()
    part.with_name(part.name + ".sha256").unlink()
    for name in ("results.csv", "results.parquet", "summary.csv", "summary.md"):
        (out / name).unlink()
    pd.testing.assert_frame_equal(_resume(out), rows, check_exact=True)
    assert part.is_file() and all(p.stat().st_mtime_ns == t for p, t in others.items())


def test_a_resume_goes_on_at_the_knobs_it_kept_whatever_the_cache_holds_now(finished, tmp_path, monkeypatch):
    """A cache filled since (here: by a run that matched on 20 other samples, so other knobs) is not read."""
    out, rows = finished
    other = run_evaluation(EvaluationConfig(out=tmp_path / "other", **{**SHIPPED, "effort_samples": 20}))
    assert not other["effort_value"].equals(rows["effort_value"])
    _no_cache_read(monkeypatch)
    pd.testing.assert_frame_equal(_resume(out), rows, check_exact=True)


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (lambda records: records[0].update(knob_value=-1.0), "knob_value -1.0 is not positive and finite"),
        (lambda records: records.pop(), "it holds the knobs of"),
        (lambda records: records[0].pop("effort"), "TypeError"),
    ],
    ids=["a knob out of range", "a record missing", "a field missing"],
)
def test_kept_knobs_that_do_not_hold_refuse_the_resume_in_one_line(finished, edit, problem):
    out, _ = finished
    path = out / "calibration.json"
    calibration = json.loads(path.read_text())
    records = calibration[runner_module.KNOBS_READ_KEY]["records"]
    records.sort(key=lambda r: (r["controller"] != "lqr", r["task"]))  # lqr has a knob: edit its record first
    edit(records)
    path.write_text(json.dumps(calibration))
    with pytest.raises(RunDirectoryError, match=f"--resume: the knobs kept in {path} do not hold .*{problem}"):
        _resume(out)
