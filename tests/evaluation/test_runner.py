"""Whole evaluations: the outputs, equal effort, trajectories that recompute every number,
determinism across workers and Ray, resuming an interrupted run, and the CLI."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import snac_gym.evaluation.execution.passes as passes_module
import snac_gym.evaluation.runner as runner_module
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.reports.summary import PAPER_TABLE_I
from snac_gym.evaluation.store import RunDirectoryError
from typer.testing import CliRunner

from snac_gym import register_policy
from snac_gym.apps.cli import app
from snac_gym.control.cost import trajectory_cost
from snac_gym.rollout import log_array, read_log

SMALL = {"samples": 6, "effort_samples": 0, "horizons": {"reach": 0.3, "track": 0.4}, "chunk_size": 2,
         "progress": False, "plots": False}  # fmt: skip


def _config(out: Path, **changes) -> EvaluationConfig:
    return EvaluationConfig(out=out, **{**SMALL, **changes})


@pytest.fixture(scope="module")
def table_run(tmp_path_factory):
    """Every built-in controller, both tasks, equal effort against SNAC, trajectories saved."""
    out = tmp_path_factory.mktemp("table")
    config = _config(out, controllers=("snac", "rnn", "svf", "dls"), save_trajectories=True, plots=True)
    return config, run_evaluation(config)


def test_results_have_one_row_per_task_controller_and_sample(table_run):
    config, results = table_run
    for name in ("results.csv", "results.parquet", "summary.csv", "summary.md", "cost_boxplot.png", "samples.csv"):
        assert (config.out / name).is_file(), name
    required = {
        "task",
        "controller",
        "sample",
        "cost",
        "cost_error",
        "cost_effort",
        "cost_smoothness",
        "final_error",
        "max_abs_u",
        "success",
        "time_to_1mm",
        "max_abs_udot",
        "steps_at_limit",
        "effort_value",
    }
    assert required <= set(results.columns)
    assert len(results) == 2 * 4 * 6 and not results.duplicated(["task", "controller", "sample"]).any()
    np.testing.assert_allclose(
        results["cost"], results[["cost_error", "cost_effort", "cost_smoothness"]].sum(axis=1), rtol=1e-12
    )
    from_csv = pd.read_csv(config.out / "results.csv")
    np.testing.assert_array_equal(from_csv["cost"].to_numpy(), results["cost"].to_numpy())  # 17 digits: exact


def test_summary_has_table_one_layout_with_paper_values_and_ratios(table_run):
    config, results = table_run
    summary = pd.read_csv(config.out / "summary.csv").set_index("controller")
    assert list(summary.index) == ["snac", "rnn", "svf", "dls"]
    for task in ("reach", "track"):
        ours = results[results["task"] == task].groupby("controller")["cost"]
        np.testing.assert_allclose(summary[f"{task}_cost"], ours.mean()[summary.index], rtol=1e-9)
        np.testing.assert_allclose(summary[f"{task}_cost_std"], ours.std()[summary.index], rtol=1e-9)
        assert (summary[f"{task}_cost_ci95_low"] < summary[f"{task}_cost"]).all()
        assert summary.loc["rnn", f"{task}_paper"] == PAPER_TABLE_I["rnn"][task]
        assert np.isnan(summary.loc["dls", f"{task}_paper"])
        qualified = summary[f"{task}_success_rate"] >= config.success_threshold
        assert (summary[f"{task}_qualified"] == qualified).all()
        assert summary[f"{task}_rank"].notna().tolist() == qualified.tolist()  # only qualified ones are ranked
        if qualified["snac"]:
            assert summary.loc["snac", f"{task}_ratio_to_snac"] == 1.0
        else:
            assert summary[f"{task}_ratio_to_snac"].isna().all()
        assert summary.loc["svf", f"{task}_paper_ratio_to_snac"] == pytest.approx(
            PAPER_TABLE_I["svf"][task] / PAPER_TABLE_I["snac"][task]
        )
    text = (config.out / "summary.md").read_text()
    assert "| Proposed (SNAC) |" in text and "49.74" in text and "cost_boxplot.png" in text


def test_the_summary_leads_with_a_table_of_at_most_eight_columns_that_marks_failures(table_run):
    """The first table a reader meets (and the CLI prints): ≤ 8 columns, cost beside success and accuracy,
    the paired comparisons; a controller under the success threshold is marked and gets no comparison."""
    config, _ = table_run
    summary = pd.read_csv(config.out / "summary.csv").set_index("controller")
    head = (config.out / "summary.md").read_text().split("\n## ")[0]
    tables = [line for line in head.splitlines() if line.startswith("| Controller |")]
    assert len(tables) == 2 and all(line.count("|") - 1 <= 8 for line in tables)
    assert "V/N [95 % CI]" in tables[0] and "success" in tables[0] and "vs the best" in tables[0]
    for task, label in (("reach", "Regulation"), ("track", "Tracking")):
        block = head.split(f"**{label}**")[1].split("\n\n")[1]
        for controller, row in summary.iterrows():
            (line,) = [line for line in block.splitlines() if line.startswith(f"| {row['label']} |")]
            if not row[f"{task}_qualified"]:
                assert "**fails**" in line and "— (fails the task)" in line, line
            else:
                assert "**fails**" not in line


def test_equal_effort_against_the_reference_or_a_visible_warning(table_run):
    config, results = table_run
    summary = pd.read_csv(config.out / "summary.csv").set_index("controller")
    text = (config.out / "summary.md").read_text()
    for task in ("reach", "track"):
        target = summary.loc["snac", f"{task}_effort"]
        assert summary.loc["snac", f"{task}_effort_role"] == "reference"
        for controller in ("rnn", "svf", "dls"):
            rows = results[(results["task"] == task) & (results["controller"] == controller)]
            effort = rows["peak_limit_fraction"].mean()  # the default statistic: the mean peak |u|/ū
            assert effort == pytest.approx(summary.loc[controller, f"{task}_effort"])
            assert (
                rows["max_abs_u"].max()
                == np.abs(
                    np.stack([log_array(read_log(_trajectory(config, row)), "u") for _, row in rows.iterrows()])
                ).max()
            )
            assert summary.loc[controller, f"{task}_median_peak_limit_fraction"] == pytest.approx(
                rows["peak_limit_fraction"].median()
            )
            if summary.loc[controller, f"{task}_effort_role"] == "matched":
                assert abs(effort / target - 1) <= config.effort_tolerance
            else:
                assert f"{controller} ({task})" in text and "Warning" in text


def test_equal_effort_matched_on_more_samples_than_are_evaluated_is_the_larger_runs(tmp_path):
    """--effort-samples: 3 samples matched on the first 6 give the 6-sample run's knobs and its first 3 rows."""
    common = {"tasks": ("reach",), "controllers": ("snac", "dls", "rnn"), "save_trajectories": True}
    full = run_evaluation(_config(tmp_path / "six", **common))
    few = run_evaluation(_config(tmp_path / "three", samples=3, effort_samples=6, **common))
    assert set(few["sample"]) == {0, 1, 2}
    expected = full[full["sample"] < 3].reset_index(drop=True).drop(columns="optimal_solve_time", errors="ignore")
    pd.testing.assert_frame_equal(few.drop(columns="optimal_solve_time", errors="ignore"), expected, check_exact=True)
    assert set(few.loc[few["controller"] == "rnn", "effort_value"]) == set(
        full.loc[full["controller"] == "rnn", "effort_value"]
    )
    summary = pd.read_csv(tmp_path / "three" / "summary.csv").set_index("controller")
    assert summary.loc["dls", "reach_effort"] == pytest.approx(
        full[full["controller"] == "dls"]["peak_limit_fraction"].mean()
    )  # the statistic that was matched: over the 6 samples
    saved = sorted(p.name for p in (tmp_path / "three" / "trajectories" / "reach" / "dls").iterdir())
    assert saved == [f"sample_{i:05d}.parquet" for i in range(3)]  # the evaluated samples' logs only
    assert "on the first 6 samples of the seed" in (tmp_path / "three" / "summary.md").read_text()
    with pytest.raises(ValueError, match="effort_samples must be between 0 and"):
        _config(tmp_path / "bad", effort_samples=-1).validate()


@pytest.mark.parametrize(("controllers", "drawn_per_task"), [(("optimal",), 3), (("optimal", "dls"), 6)])
def test_the_effort_set_is_drawn_only_where_knobs_are_matched(tmp_path, monkeypatch, controllers, drawn_per_task):
    """A run of the reference alone matches no knob: it draws the samples it reports, not the effort set beyond them
    (a 50-sample question drew 950 more a task, most of its time); with a controller to match, it draws both."""
    drawn: list[tuple[str, int]] = []
    draw = runner_module.generate_samples

    def counted(kinematics, space, seed, task, indices):
        drawn.extend((task, index) for index in indices)
        return draw(kinematics, space, seed, task, indices)

    monkeypatch.setattr(runner_module, "generate_samples", counted)
    rows = run_evaluation(_config(tmp_path / "run", samples=3, effort_samples=6, controllers=controllers))
    assert sorted(drawn) == [(task, i) for task in ("reach", "track") for i in range(drawn_per_task)]
    assert set(rows["sample"]) == {0, 1, 2} and set(rows["controller"]) == set(controllers)


def _trajectory(config: EvaluationConfig, row: pd.Series) -> Path:
    return config.out / "trajectories" / row["task"] / row["controller"] / f"sample_{row['sample']:05d}.parquet"


def test_saved_trajectories_recompute_every_reported_number(table_run):
    config, results = table_run
    for _, row in results.iterrows():
        log = read_log(
            config.out / "trajectories" / row["task"] / row["controller"] / f"sample_{row['sample']:05d}.parquet"
        )
        dt = log.attrs["dt"]
        assert list(log.columns[:1]) == ["t"] and len(log) == round(row["horizon"] / dt)
        errors, commands = log_array(log, "e"), log_array(log, "u")
        terms = trajectory_cost(errors, commands, dt)
        assert float(terms.total) == pytest.approx(row["cost"], rel=1e-12)
        assert float(terms.smoothness) == pytest.approx(row["cost_smoothness"], rel=1e-12)
        assert np.linalg.norm(log.attrs["final_e"]) == pytest.approx(row["final_error"], rel=1e-12)
        assert np.abs(commands).max() == row["max_abs_u"]
        np.testing.assert_allclose(errors, log_array(log, "x") - log_array(log, "x_d"), atol=1e-15)


def test_explicit_target_matches_every_controller_and_workers_do_not_change_results(tmp_path):
    register_policy(
        "evaltest-dls", "snac_gym.baselines.dls:DLSPolicy", overwrite=True
    )  # a run-time registration reaches forked workers
    common = {
        "controllers": ("evaltest-dls", "rnn"),
        "tasks": ("reach",),
        "effort_statistic": "median-peak",
        "effort_target": 0.4,
    }
    serial = run_evaluation(_config(tmp_path / "serial", **common))
    parallel = run_evaluation(_config(tmp_path / "parallel", workers=2, **common))
    pd.testing.assert_frame_equal(serial, parallel, check_exact=True)  # bit for bit, matches run concurrently
    efforts = serial.groupby("controller")["peak_limit_fraction"].median()
    assert ((efforts / 0.4 - 1).abs() <= 0.02).all(), efforts
    assert serial.groupby("controller")["effort_value"].nunique().eq(1).all()


def test_an_interrupted_run_resumes_without_losing_or_repeating_samples(tmp_path, monkeypatch):
    config = _config(tmp_path / "run", controllers=("dls", "svf"), effort_reference="dls")
    reference = run_evaluation(dataclasses.replace(config, out=tmp_path / "reference"))
    real_run_job = passes_module.run_job
    calls = {"n": 0}

    def interrupted(job):
        calls["n"] += 1
        if calls["n"] == 9:  # after the reference passes (6 jobs), inside svf's knob search
            raise KeyboardInterrupt
        return real_run_job(job)

    monkeypatch.setattr(passes_module, "run_job", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_evaluation(config)
    parts = {p: p.stat().st_mtime_ns for p in (config.out / "parts").glob("*.parquet")}
    assert len(parts) == 6 and not (config.out / "results.csv").exists()

    with pytest.raises(RunDirectoryError, match="pass --resume"):
        run_evaluation(config)
    with pytest.raises(RunDirectoryError, match="seed: stored 0, now 1"):
        run_evaluation(dataclasses.replace(config, resume=True, seed=1))

    monkeypatch.setattr(passes_module, "run_job", real_run_job)
    resumed = run_evaluation(dataclasses.replace(config, resume=True))
    assert {p: p.stat().st_mtime_ns for p in parts} == parts  # completed jobs were not run again
    pd.testing.assert_frame_equal(resumed, reference, check_exact=True)
    assert not resumed.duplicated(["task", "controller", "sample"]).any() and len(resumed) == 2 * 2 * 6


def test_pybullet_engine_runs_through_the_env(tmp_path):
    config = _config(
        tmp_path / "pb", controllers=("dls",), samples=2, engine="pybullet", save_trajectories=True, match_effort=False
    )
    results = run_evaluation(config)
    assert len(results) == 4 and set(results["engine"]) == {"pybullet"}
    log = read_log(config.out / "trajectories" / "track" / "dls" / "sample_00001.parquet")
    assert float(trajectory_cost(log_array(log, "e"), log_array(log, "u"), log.attrs["dt"]).total) == pytest.approx(
        results.loc[(results["task"] == "track") & (results["sample"] == 1), "cost"].item(), rel=1e-12
    )


def test_knob_searches_with_long_rollouts_run_on_fewer_samples(tmp_path):
    from snac_gym.evaluation.controllers import ControllerSpec
    from snac_gym.evaluation.effort.matching import EffortMatcher

    def matcher(config):
        return EffortMatcher(passes_module.EvaluationRun(config, None, None, {"reach": list(range(1000))}, None))

    config = _config(tmp_path, samples=1000, horizons={"reach": 8.0}, effort_statistic="median-peak")
    median = matcher(config)
    spec = ControllerSpec("dls", {}, "gain", 2.0)
    assert median.screening_count("reach", spec, 40, 1) == 1000  # short rollouts: every sample
    assert median.screening_count("reach", spec, 476, 1) == 211  # 10 % of a full pass's sample-steps
    assert median.screening_count("reach", spec, 1000, 1) == 100  # never fewer than 100
    for_max = matcher(dataclasses.replace(config, effort_statistic="max"))
    assert for_max.screening_count("reach", spec, 166, 1) == 1000  # up to 1/6 of a pass: every sample
    assert for_max.screening_count("reach", spec, 476, 1) == 351
    pinned = matcher(dataclasses.replace(config, calibration_samples=30))
    assert pinned.screening_count("reach", spec, 1000, 1) == 30


def test_resume_needs_a_run(tmp_path):
    with pytest.raises(RunDirectoryError, match="holds no run"):
        run_evaluation(_config(tmp_path / "empty", controllers=("dls",), resume=True))


def test_cli_exports_reads_samples_and_reports(tmp_path):
    cli = CliRunner()
    samples = tmp_path / "samples.csv"
    exported = cli.invoke(
        app,
        [
            "evaluate",
            "--task",
            "reach",
            "--samples",
            "3",
            "--seed",
            "5",
            "--export-samples",
            str(samples),
            "--export-only",
        ],
    )
    assert exported.exit_code == 0, exported.output
    assert len(pd.read_csv(samples)) == 3
    result = cli.invoke(
        app,
        [
            "evaluate",
            "--out",
            str(tmp_path / "out"),
            "--task",
            "reach",
            "--samples-file",
            str(samples),
            "--controllers",
            "dls,svf",
            "--horizon",
            "reach=0.2",
            "--no-match-effort",
            "--no-progress",
            "--param",
            "svf.nu=5",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "Trajectory cost V/N" in result.output and "wall time" in result.output
    results = pd.read_csv(tmp_path / "out" / "results.csv")
    assert sorted(results["sample"].unique()) == [0, 1, 2] and set(results["horizon"]) == {0.2}


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--horizon", "walk=3"], "unknown task 'walk'"),
        (["--controllers", "nope"], "unknown controller 'nope'"),
        (["--task", "wave"], "--task must be both or a registered task (reach, track)"),
        (["--param", "svf"], "use CONTROLLER.KEY=VALUE"),
        (
            ["--effort-statistic", "mean"],
            "--effort-statistic must be one of max, median-peak, mean-peak, peak-ratio, got 'mean'",
        ),
    ],
)
def test_cli_rejects_bad_options_with_a_message(tmp_path, arguments, message):
    result = CliRunner().invoke(app, ["evaluate", "--out", str(tmp_path / "x"), "--samples", "2", *arguments])
    assert result.exit_code == 2 and message in result.output


def test_cli_names_the_bad_row_of_a_samples_file(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text(
        "task,q0_0,q0_1,q0_2,q0_3,q0_4,q0_5,target_0,target_1,target_2\n"
        "reach,-0.51,-1.04,1.48,-1.82,-1.45,-1.62,-0.658,oops,0.407\n"
    )
    result = CliRunner().invoke(
        app, ["evaluate", "--out", str(tmp_path / "x"), "--task", "reach", "--samples-file", str(bad)]
    )
    assert result.exit_code == 2 and "row 1 (line 2), column 'target_1': 'oops' is not a number" in result.output


def test_max_statistic_refines_on_the_critical_samples_the_screening_missed(tmp_path):
    """With 2 screening samples the search overshoots (the set's maximum comes from other samples);
    the refinement on the samples at the threshold recovers the knob that screening all gives."""
    common = {"controllers": ("snac", "dls"), "tasks": ("reach",), "effort_statistic": "max"}
    screened_all = run_evaluation(_config(tmp_path / "all", calibration_samples=6, **common))
    refined = run_evaluation(_config(tmp_path / "two", calibration_samples=2, **common))
    calibration = json.loads((tmp_path / "two" / "calibration.json").read_text())
    first, second = calibration["reach/dls/search1"], calibration["reach/dls/search2"]
    assert first["screening_samples"] == 2 and first["sample_ids"] is None
    critical = refined[(refined["controller"] == "dls")]
    assert set(second["sample_ids"]) - {0, 1}  # critical samples outside the screening set
    knob = critical["effort_value"].iloc[0]
    assert knob == second["value"] < first["value"]
    assert knob == pytest.approx(
        screened_all.loc[screened_all["controller"] == "dls", "effort_value"].iloc[0], rel=0.02
    )
    summary = pd.read_csv(tmp_path / "two" / "summary.csv").set_index("controller")
    assert summary.loc["dls", "reach_effort_passes"] == 2 and summary.loc["dls", "reach_effort_role"] == "matched"


class _CappedElbow:
    """Drives the elbow at gain·c rad/s, c = 3.0 on two chosen episodes and 3.14 on the others: its
    effort (max |u|) saturates, lower on the screening samples than on the whole set."""

    effort_parameter = "gain"
    low_seeds: frozenset[int] = frozenset()

    def __init__(self, env, gain: float = 0.5) -> None:
        from snac_gym.policies.base import PolicyContext

        self.context = PolicyContext.from_env(env)
        self.gain = float(gain)
        self.caps = np.array([3.14])

    def reset_batch(self, seeds):
        self.caps = np.array([3.0 if seed in self.low_seeds else 3.14 for seed in seeds])

    def act_batch(self, obs_batch):
        commands = np.zeros((len(obs_batch), 6))
        commands[:, 2] = np.minimum(self.gain, 1.0) * self.caps
        return commands


def test_a_failed_knob_search_is_labelled_unmatched_even_when_the_full_pass_lands_near(tmp_path):
    from snac_gym.evaluation.samples import policy_seed

    _CappedElbow.low_seeds = frozenset(policy_seed(0, "reach", i) for i in (0, 1))
    register_policy("evaltest-capped", _CappedElbow, overwrite=True)
    config = _config(
        tmp_path,
        controllers=("evaltest-capped",),
        tasks=("reach",),
        samples=4,
        calibration_samples=2,
        effort_target=3.19,
        effort_statistic="max",
    )
    results = run_evaluation(config)
    summary = pd.read_csv(tmp_path / "summary.csv").set_index("controller")
    assert results["max_abs_u"].max() == pytest.approx(3.14)  # within 2 % of 3.19 over the whole set...
    assert summary.loc["evaltest-capped", "reach_effort_role"] == "unmatched"  # ...but the search failed
    note = summary.loc["evaltest-capped", "reach_effort_note"]
    assert "knob search failed" in note and "reached 3.14 (target 3.19)" in note
    # the least aggressive knob tried that reaches the controller's own ceiling (gain 1 reaches it)
    assert 1.0 <= summary.loc["evaltest-capped", "reach_effort_value"] <= 1.1
    assert "unmatched" in (tmp_path / "summary.md").read_text()


def test_hjb_cost_runs_give_the_same_numbers_with_one_or_two_workers(tmp_path):
    """snac, snac-hjb, lqr and the optimum under the HJB cost, Q = 4I: bit-identical with 1 or 2 workers."""
    common = {
        "controllers": ("snac", "snac-hjb", "lqr", "optimal"),
        "match_effort": False,
        "cost": "hjb",
        "q_scale": 4.0,
        "horizons": {"reach": 0.5, "track": 0.5},
    }
    serial = run_evaluation(_config(tmp_path / "serial", **common))
    parallel = run_evaluation(_config(tmp_path / "parallel", workers=2, **common))
    timing = ["optimal_solve_time"]
    pd.testing.assert_frame_equal(serial.drop(columns=timing), parallel.drop(columns=timing), check_exact=True)
    np.testing.assert_allclose(serial["cost"], serial["cost_hjb"], rtol=0)  # the HJB cost has no u̇ term
    critics = serial[serial["controller"].isin(["snac", "snac-hjb"])]
    assert critics["hjb_ratio_median"].notna().all() and critics["hjb_residual_median"].notna().all()
    assert serial.loc[serial["controller"] == "lqr", "hjb_ratio_median"].isna().all()
    assert critics.loc[critics["task"] == "reach", "critic_error_final"].notna().all()


def test_the_summarys_times_are_the_ones_timings_json_holds(tmp_path, monkeypatch):
    """summary.md's 0.1 s figures are timings.json's, rounded once. A clock that ticks 0.15004 s a reading puts a
    phase within a millisecond of a rounding boundary: 0.15004 s reads 0.2 s, timings.json's 0.150 reads 0.1 s."""
    import itertools
    import time
    import types

    ticks = itertools.count()
    clock = types.SimpleNamespace(**{name: getattr(time, name) for name in dir(time) if not name.startswith("_")})
    clock.perf_counter = lambda: next(ticks) * 0.15004
    monkeypatch.setattr(runner_module, "time", clock)
    config = _config(tmp_path / "run", samples=1, controllers=("dls",))
    run_evaluation(config)
    timings = json.loads((config.out / "timings.json").read_text())
    summary = " ".join((config.out / "summary.md").read_text().split())
    assert timings["samples"] == 0.15  # one tick: the boundary case
    assert f"Wall time {timings.pop('total'):.1f} s" in summary
    for name, seconds in timings.items():
        assert f"{name} {seconds:.1f} s" in summary, (name, seconds, summary[-600:])
