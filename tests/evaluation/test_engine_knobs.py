"""A run in a physics engine matches its effort on the kinematic model and runs its samples in its engine: its knobs
are the kinematic run's bit for bit, shared with it through the calibration cache, and kept for a resume."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation import runner as runner_module
from snac_gym.evaluation.effort import cache
from snac_gym.evaluation.effort.matching import MODEL_ORIGIN

#: dls matched to lqr's effort (no shipped knobs: lqr is not the default reference), on 8 samples, 2 reported.
SETTINGS = {
    "controllers": ("lqr", "dls"),
    "effort_reference": "lqr",
    "tasks": ("reach",),
    "samples": 2,
    "effort_samples": 8,
    "horizons": {"reach": 2.0},
    "progress": False,
    "plots": False,
}


def _knobs(rows: pd.DataFrame) -> dict[str, float]:
    return {name: float(group["effort_value"].iloc[0]) for name, group in rows.groupby("controller")}


def test_a_physics_run_matches_on_the_model_runs_in_its_engine_and_shares_its_knobs(tmp_path, monkeypatch):
    kinematic = run_evaluation(EvaluationConfig(out=tmp_path / "kinematic", calibration_cache=False, **SETTINGS))
    monkeypatch.setenv(cache.SWITCH_ENV, "1")  # the tests run with the calibration cache off (tests/conftest.py)
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "pybullet"
    physics = run_evaluation(EvaluationConfig(out=out, engine="pybullet", **SETTINGS))

    # The knobs are the kinematic run's, bit for bit; the rollouts are PyBullet's.
    assert _knobs(physics) == _knobs(kinematic)
    assert set(physics["engine"]) == {"pybullet"} and list(physics["sample"]) == list(kinematic["sample"])
    cost = physics["cost"].to_numpy()
    assert not np.array_equal(cost, kinematic["cost"].to_numpy())  # another plant
    np.testing.assert_allclose(cost, kinematic["cost"].to_numpy(), rtol=1e-2)
    kept = json.loads((out / "calibration.json").read_text())[runner_module.KNOBS_READ_KEY]
    assert kept["stamp"] == {"origin": MODEL_ORIGIN}
    assert "**The knobs were matched on the kinematic model**" in (out / "summary.md").read_text()
    assert "on the kinematic model (the reported rollouts are pybullet's)" in (out / "summary.md").read_text()

    # A kinematic run at the same settings reads them from the cache: its rows are the matching run's, bit for bit.
    again = run_evaluation(EvaluationConfig(out=tmp_path / "again", **SETTINGS))
    pd.testing.assert_frame_equal(again.drop(columns="solve_time", errors="ignore"),
                                  kinematic.drop(columns="solve_time", errors="ignore"), check_exact=True)  # fmt: skip
    assert "they come from the calibration cache" in (tmp_path / "again" / "summary.md").read_text()

    # A resume goes on at the knobs the run kept, reading neither the cache nor the shipped file.
    def refuse(*args, **kwargs):
        raise AssertionError("a resumed run read the calibration cache or the shipped knobs")

    monkeypatch.setattr(runner_module, "read_records", refuse)
    monkeypatch.setattr(runner_module, "read_shipped", refuse)
    for name in ("results.csv", "results.parquet", "summary.csv", "summary.md"):
        (out / name).unlink()
    resumed = run_evaluation(EvaluationConfig(out=out, engine="pybullet", resume=True, **SETTINGS))
    pd.testing.assert_frame_equal(resumed, physics, check_exact=True)


def test_a_physics_run_at_the_defaults_reads_the_shipped_knobs(tmp_path, monkeypatch):
    """The shipped knobs are the kinematic model's: a first run in MuJoCo or PyBullet reads them instead of matching
    on 1000 samples in its engine (tens of minutes in PyBullet)."""
    monkeypatch.setenv(cache.SWITCH_ENV, "1")
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "cache"))

    def refuse(*args, **kwargs):
        raise AssertionError("matched effort instead of reading the shipped knobs")

    monkeypatch.setattr(runner_module, "controller_passes", refuse)
    config = {
        "controllers": ("snac", "dls", "lqr"),
        "tasks": ("reach",),
        "samples": 1,
        "progress": False,
        "plots": False,
    }
    rows = run_evaluation(EvaluationConfig(out=tmp_path / "run", engine="pybullet", **config))
    assert set(rows["engine"]) == {"pybullet"}
    assert "knobs shipped with snac-gym" in (tmp_path / "run" / "summary.md").read_text()


@pytest.mark.parametrize("engine", ["pybullet", "mujoco"])
def test_the_model_match_is_timed_apart_in_either_engine(tmp_path, engine):
    pytest.importorskip(engine)
    out = tmp_path / engine
    run_evaluation(EvaluationConfig(out=out, engine=engine, calibration_cache=False, **SETTINGS))
    timings = json.loads((out / "timings.json").read_text())
    assert {"reference passes on the kinematic model", "effort matching on the kinematic model"} <= set(timings)
    assert "passes at cached knobs" in timings


def test_a_physics_run_without_matching_runs_nothing_on_the_model(tmp_path):
    out = tmp_path / "run"
    rows = run_evaluation(EvaluationConfig(out=out, engine="pybullet", match_effort=False, **SETTINGS))
    assert set(rows["engine"]) == {"pybullet"}
    assert not [phase for phase in json.loads((out / "timings.json").read_text()) if "kinematic model" in phase]
    summary = (out / "summary.md").read_text()
    assert "No effort matching" in summary and "kinematic model" not in summary


def test_a_physics_run_cut_short_after_the_models_match_resumes_to_the_same_rows(tmp_path):
    """Cut after the model's passes, before its knobs were kept and before any pass in the engine: the resume takes the
    model's parts as they are (rerunning none) and runs the engine's again, to the same rows."""
    out = tmp_path / "run"
    config = {"engine": "pybullet", "calibration_cache": False, **SETTINGS}
    rows = run_evaluation(EvaluationConfig(out=out, **config))
    calibration = json.loads((out / "calibration.json").read_text())
    del calibration[runner_module.KNOBS_READ_KEY]
    (out / "calibration.json").write_text(json.dumps(calibration))
    model_parts = {}
    for part in (out / "parts").glob("*.parquet"):
        if set(pd.read_parquet(part)["engine"]) == {"pybullet"}:
            part.unlink()
            part.with_name(part.name + ".sha256").unlink()
        else:
            model_parts[part] = part.stat().st_mtime_ns
    assert model_parts
    for name in ("results.csv", "results.parquet", "summary.csv", "summary.md"):
        (out / name).unlink()
    resumed = run_evaluation(EvaluationConfig(out=out, resume=True, **config))
    pd.testing.assert_frame_equal(resumed, rows, check_exact=True)
    assert all(part.stat().st_mtime_ns == stamp for part, stamp in model_parts.items())
