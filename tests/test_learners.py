"""docs/scripts/learners.py and learners_report.py (the learners table of docs/rl.md): the IQM and its stratified
bootstrap against hand computations, the profile's count of failures, the resume, the CLI's refusal, and the
observation the trained models are given."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

from snac_gym.common.extras import install_line

SCRIPTS = Path(__file__).resolve().parents[1] / "docs" / "scripts"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses resolve their module by name
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def learners():
    # the script reads the shipped rl-zoo3 hyperparameter files with PyYAML, which comes with the zoo extra
    pytest.importorskip("yaml", reason=f"needs PyYAML, installed with the 'zoo' extra: {install_line('zoo')}")
    return _load("learners")


@pytest.fixture(scope="module")
def report():
    pytest.importorskip("rliable", reason="needs the zoo extra (rliable), left out on Python 3.12 and 3.13")
    return _load("learners_report")


def test_the_iqm_is_the_mean_of_the_middle_half_of_runs_times_tasks(report):
    assert report.iqm(np.arange(1.0, 9.0)[:, None]) == pytest.approx(4.5)  # 8 runs: mean of 3, 4, 5, 6
    scores = np.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0], [4.0, 40.0]])
    assert report.iqm(scores) == pytest.approx((3 + 4 + 10 + 20) / 4)  # the 8 entries, 2 trimmed at each end
    assert report.iqm(np.array([[5.0], [1.0], [9.0]])) == pytest.approx(5.0)  # 3 runs: nothing trimmed, the mean
    stack = np.random.default_rng(0).normal(size=(20, 3, 2))
    assert np.allclose(report.iqm_rows(stack), [report.iqm(sample) for sample in stack])


def test_the_bootstrap_resamples_runs_within_each_task(report):
    scores = np.array([[1.0, 3.0], [1.0, 3.0], [1.0, 3.0]])  # each task's runs agree: no resample can differ
    point, low, high = report.stratified_bootstrap(scores, lambda x: x.mean(axis=1), reps=200)
    assert np.array_equal(point, [1.0, 3.0]) and np.array_equal(low, [1.0, 3.0]) and np.array_equal(high, [1.0, 3.0])
    spread = np.arange(1.0, 9.0)[:, None]
    point, low, high = report.stratified_bootstrap(spread, lambda x: report.iqm_rows(x)[:, None], reps=2000)
    assert point[0] == pytest.approx(4.5) and 1.0 < low[0] < 4.5 < high[0] < 8.0
    again = report.stratified_bootstrap(spread, lambda x: report.iqm_rows(x)[:, None], reps=2000)
    assert again[1][0] == low[0] and again[2][0] == high[0]  # seeded: the same interval every time


def test_a_failed_episode_is_never_within_tau_however_cheap(report):
    scores = pd.DataFrame(
        {
            "learner": "sac",
            "task": "reach",
            "seed": 0,
            "sample": [0, 1, 2, 3],
            "success": [True, True, False, True],
            "ratio": [1.0, 2.0, 0.5, 5.0],  # the failure is the cheapest
        }
    )
    assert np.array_equal(report.episode_ratios(scores, "sac", "reach"), [[1.0, 2.0, 0.5, 5.0]])  # at its cost
    ratios = report.episode_ratios(scores, "sac", "reach", failures="never")
    assert np.array_equal(ratios, [[1.0, 2.0, np.inf, 5.0]])
    fractions = report.within(ratios[None], np.array([0.9, 1.0, 2.0, 1e4]))[0]
    assert np.allclose(fractions, [0.0, 0.25, 0.5, 0.75])


def test_the_table_gives_each_task_and_both(report):
    runs = pd.DataFrame(
        {
            "learner": ["td3"] * 6,
            "task": ["reach"] * 3 + ["track"] * 3,
            "seed": [0, 1, 2] * 2,
            "success": [1.0, 0.5, 0.0, 1.0, 1.0, 1.0],
            "median_ratio": [2.0, 4.0, 6.0, 1.0, 2.0, 30.0],
        }
    )
    table = report.summary(runs, reps=500).set_index("task")
    assert table.loc["reach", "median_ratio_iqm"] == pytest.approx(4.0)  # 3 runs: their mean
    assert table.loc["both", "median_ratio_iqm"] == pytest.approx((2 + 2 + 4 + 6) / 4)  # 6 values, 1 trimmed each end
    assert table.loc["track", "success_low"] == table.loc["track", "success_high"] == 1.0
    low = table.loc["reach", "median_ratio_low"]
    assert 2.0 < low < 4.0  # the mean of a resample of (2, 4, 6) is 2 only when all three draws are the 2
    high = 100 * table.loc["reach", "success_high"]
    row = f"| reach | TD3 | 3 | 50 % [0, {high:.0f}] | 4.000 [{low:.3f}, 6.000] |"
    assert row in report.markdown(table.reset_index()).splitlines()


def test_resuming_skips_a_scored_job_and_only_scores_a_trained_one(learners, tmp_path, monkeypatch):
    done, trained, fresh = (learners.Job("sac", "reach", seed, 100, 5, 62, str(tmp_path)) for seed in (0, 1, 2))
    for job in (done, trained):
        job.folder.mkdir(parents=True)
    pd.DataFrame({"success": [True], "ratio": [1.5]}).to_csv(done.folder / "scores.csv", index=False)
    (trained.folder / "model.zip").write_bytes(b"")
    assert learners.pending([done, trained, fresh]) == [trained, fresh]
    calls = []
    monkeypatch.setattr(learners, "train", lambda job: calls.append(("train", job.seed)))
    monkeypatch.setattr(
        learners, "score", lambda job: calls.append(("score", job.seed)) or pd.DataFrame({"success": [1], "ratio": [2]})
    )
    assert learners.run_job(done)["action"] == "kept"
    assert learners.run_job(trained)["action"] == "scored"
    assert learners.run_job(fresh)["action"] == "trained and scored"
    assert calls == [("score", 1), ("train", 2), ("score", 2)]


def test_an_unknown_learner_is_refused_in_one_line(learners, capsys):
    assert learners.main(["--learners", "ppo,a2c", "--out", "unused"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'a2c'" in err and "ppo, sac, td3, tqc" in err


def test_the_model_sees_what_the_v1_env_shows(learners):
    """The evaluator's observation (physical units, a -v0 env's) turned into the -v1 env's, to the bit."""
    env_id = learners.TASKS["track"]
    low, high = learners.observation_bounds(env_id)
    v0 = gym.make(env_id.replace("-v1", "-v0"), physics="kinematic")
    v1 = gym.make(env_id, physics="kinematic")
    obs0, _ = v0.reset(seed=3)
    obs1, _ = v1.reset(seed=3)
    action = np.full(v1.action_space.shape, 0.7, dtype=np.float32)
    for _ in range(3):
        assert np.array_equal(learners.env_observation(obs0, low, high), obs1) and obs1.dtype == np.float32
        obs0, *_ = v0.step(action.astype(np.float64) * v0.unwrapped.velocity_limits)
        obs1, *_ = v1.step(action)
    v0.close()
    v1.close()


def test_docs_rl_shows_the_shipped_table_and_the_table_is_the_shipped_summarys(report):
    """docs/data/learners holds what the report wrote; rl.md shows its table.md as written (mkdocs.yml keeps that file
    out of the nav), and the table is the one the report makes of the shipped summary.csv."""
    data = Path(__file__).resolve().parents[1] / "docs" / "data" / "learners"
    table = (data / "table.md").read_text()
    assert table in (data.parents[1] / "rl.md").read_text()
    assert report.markdown(pd.read_csv(data / "summary.csv")) == table
