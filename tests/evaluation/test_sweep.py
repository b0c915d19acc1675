"""The trade-off sweep (evaluation/sweep.py, ``snac-gym evaluate --sweep``): the knob grid asked
for, V/N equal to a plain evaluation at the same knob, the equal-effort point of the main run,
the figure, determinism across workers, resuming, and the CLI's bounds."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.sweep import MAX_POINTS, SWEEP_COLUMNS, run_sweep
from typer.testing import CliRunner

from snac_gym.apps.cli import app
from snac_gym.policies.registry import make_policy

SMALL = {
    "samples": 4,
    "effort_samples": 0,
    "horizons": {"reach": 0.3, "track": 0.5},
    "chunk_size": 2,
    "progress": False,
    "controllers": ("dls", "lqr"),
}
POINTS, SPAN = 3, 4.0


def _config(out: Path, **changes) -> EvaluationConfig:
    return EvaluationConfig(out=out, **{**SMALL, **changes})


def _default_knob(name: str, task: str) -> tuple[str, float]:
    """The knob and its default, read off a freshly built policy (not from the runner)."""
    policy = make_policy(name, policy_context("ur10", 1.0 / 125.0, task))
    knob = type(policy).effort_parameter
    return knob, float(getattr(policy, knob))


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    config = _config(tmp_path_factory.mktemp("sweep") / "run", workers=2)
    return config, run_sweep(config, points=POINTS, span=SPAN)


def test_sweep_csv_holds_the_grid_asked_for_per_controller_and_task(swept):
    config, sweep = swept
    on_disk = pd.read_csv(config.out / "sweep.csv", keep_default_na=False, na_values=[""])
    assert list(on_disk.columns) == list(SWEEP_COLUMNS)
    np.testing.assert_array_equal(on_disk["knob_value"].to_numpy(), sweep["knob_value"].to_numpy())  # 17 digits
    for task in config.tasks:
        for name in config.controllers:
            knob, default = _default_knob(name, task)
            rows = sweep[(sweep["task"] == task) & (sweep["controller"] == name)]
            assert (rows["knob"] == knob).all()
            grid = rows.loc[rows["grid_exponent"].notna(), "knob_value"].to_numpy()
            np.testing.assert_allclose(grid, default * SPAN ** np.array([-1.0, 0.0, 1.0]), rtol=1e-15)
            assert len(rows) in (POINTS, POINTS + 1)  # + the main run's point when it is off the grid
            assert rows["knob_value"].is_monotonic_increasing and rows["knob_value"].is_unique
            assert (rows["n"] == config.samples).all()


def test_each_point_equals_a_plain_evaluation_at_that_knob(swept, tmp_path):
    """V/N, success, accuracy and peak effort of two grid points, recomputed by a separate run."""
    config, sweep = swept
    chosen = {}
    for name in config.controllers:
        knob, default = _default_knob(name, "reach")
        chosen[name] = (knob, default * SPAN)  # the top of the grid: not a point the main run evaluated
    plain = run_evaluation(
        _config(
            tmp_path / "plain",
            match_effort=False,
            controller_kwargs={name: {knob: value} for name, (knob, value) in chosen.items()},
        )
    )
    for task in config.tasks:
        for name, (_, value) in chosen.items():
            rows = plain[(plain["task"] == task) & (plain["controller"] == name)]
            point = sweep[(sweep["task"] == task) & (sweep["controller"] == name) & (sweep["knob_value"] == value)]
            assert len(point) == 1
            point = point.iloc[0]
            np.testing.assert_allclose(point["cost"], rows["cost"].mean(), rtol=1e-12)
            np.testing.assert_allclose(point["cost_hjb"], rows["cost_hjb"].mean(), rtol=1e-12)
            np.testing.assert_allclose(point["cost_table1_first"], rows["cost_table1_first"].mean(), rtol=1e-12)
            assert point["success_rate"] == rows["success"].mean()
            accuracy = rows["final_error"] if task == "reach" else rows["median_error_2nd_half"]
            np.testing.assert_allclose(point["median_error"], np.median(accuracy), rtol=1e-12)
            assert point["max_abs_u_max"] == rows["max_abs_u"].max()
            np.testing.assert_allclose(point["max_abs_u_median"], np.median(rows["max_abs_u"]), rtol=1e-12)
            assert point["qualified"] == (rows["success"].mean() >= config.success_threshold)


def test_the_equal_effort_point_is_the_main_runs_matched_knob(swept):
    config, sweep = swept
    summary = pd.read_csv(config.out / "summary.csv").set_index("controller")
    results = pd.read_parquet(config.out / "results.parquet")
    for task in config.tasks:
        for name in config.controllers:
            rows = sweep[(sweep["task"] == task) & (sweep["controller"] == name)]
            main = rows[rows["main_run"]]
            assert len(main) == 1 and (rows["effort_role"] == "").sum() == len(rows) - 1
            point = main.iloc[0]
            np.testing.assert_allclose(point["knob_value"], summary.loc[name, f"{task}_effort_value"], rtol=1e-9)
            role = summary.loc[name, f"{task}_effort_role"]
            assert point["effort_role"] == role and role in ("reference", "matched")
            assert point["equal_effort"] and rows["equal_effort"].sum() == 1
            # The main run's own rows at that knob give the same V/N.
            own = results[(results["task"] == task) & (results["controller"] == name)]
            assert (own["effort_value"] == point["knob_value"]).all()
            np.testing.assert_allclose(point["cost"], own["cost"].mean(), rtol=1e-12)
    # dls is the reference (snac is not evaluated): its point is its default, on the grid.
    reference = sweep[(sweep["controller"] == "dls") & sweep["equal_effort"]]
    assert (reference["grid_exponent"] == 0).all()


def test_a_sweep_after_a_match_on_the_effort_set_gives_the_main_runs_rows_at_its_point(tmp_path):
    """With an effort set larger than the run (12 samples for 4, as every default run has 1000), the match's full
    passes hold other samples than the sweep's: the sweep was refused ("belongs to other samples") at its first point.
    Its point at the matched knob, run on the run's own samples, gives the main run's V/N."""
    config = _config(tmp_path / "run", effort_samples=12, chunk_size=8, plots=False)  # chunk 0: samples 0-7, or 0-3
    sweep = run_sweep(config, points=POINTS, span=SPAN)
    results = pd.read_parquet(config.out / "results.parquet")
    for task in config.tasks:
        for name in config.controllers:
            rows = sweep[(sweep["task"] == task) & (sweep["controller"] == name)]
            (point,) = rows[rows["main_run"]].itertuples()
            own = results[(results["task"] == task) & (results["controller"] == name)]
            assert len(own) == point.n == 4 and (own["effort_value"] == point.knob_value).all()
            np.testing.assert_allclose(point.cost, own["cost"].mean(), rtol=1e-12)
    # The effort set's passes (12 samples: 2 parts each) and the run's (4: 1 part each) have parts of their own.
    assert len(list((config.out / "parts").glob("reach__lqr__*.parquet"))) >= 2 + POINTS + 1


def test_the_figure_is_written(swept):
    config, _ = swept
    png = (config.out / "tradeoff.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_same_sweep_with_one_worker_and_on_resume(swept, tmp_path):
    config, sweep = swept
    serial = run_sweep(
        dataclasses.replace(config, out=tmp_path / "serial", workers=1, plots=False), points=POINTS, span=SPAN
    )
    pd.testing.assert_frame_equal(serial, sweep, check_exact=True)
    assert not list((tmp_path / "serial").glob("*.png"))  # --no-plots: the tables only
    assert "cost_boxplot.png" not in (tmp_path / "serial" / "summary.md").read_text()
    copy = tmp_path / "interrupted"
    shutil.copytree(config.out, copy)
    removed = sorted((copy / "parts").glob("*.parquet"))[-1]
    removed.unlink()  # an interrupted sweep: one job lost
    # Resumed without figures: those of the first attempt are removed, not left beside newer tables.
    assert {"cost_boxplot.png", "tradeoff.png"} <= {p.name for p in copy.iterdir()}
    resumed = run_sweep(dataclasses.replace(config, out=copy, resume=True, plots=False), points=POINTS, span=SPAN)
    pd.testing.assert_frame_equal(resumed, sweep, check_exact=True)
    assert removed.is_file() and not list(copy.glob("*.png"))


@pytest.mark.parametrize("points", ["0", "1", str(MAX_POINTS + 1), "100000"])
def test_bad_sweep_points_give_a_one_line_error(points, tmp_path):
    out = tmp_path / "x"
    result = CliRunner().invoke(
        app,
        ["evaluate", "--out", str(out), "--samples", "2", "--controllers", "dls", "--sweep", "--sweep-points", points],
    )
    assert result.exit_code == 2
    assert result.output.strip() == f"error: --sweep-points must be between 2 and {MAX_POINTS}, got {points}"
    assert not out.exists()  # refused before anything ran


def test_cli_sweep_says_where_its_files_went(tmp_path):
    out = tmp_path / "cli"
    result = CliRunner().invoke(
        app,
        [
            "evaluate",
            "--out",
            str(out),
            "--samples",
            "2",
            "--horizon",
            "0.2",
            "--controllers",
            "dls,lqr",
            "--sweep",
            "--sweep-points",
            "2",
            "--no-progress",
            "--effort-samples",
            "0",
        ],
    )
    assert result.exit_code == 0, result.output
    assert f"{out / 'sweep.csv'}" in result.output and f"{out / 'tradeoff.png'}" in result.output
    sweep = pd.read_csv(out / "sweep.csv")
    # 2 grid points + the main run's knob (off a grid of 2) per controller and task.
    assert set(sweep["controller"]) == {"dls", "lqr"} and len(sweep) == 2 * 2 * 3 and sweep["main_run"].sum() == 4
