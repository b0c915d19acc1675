"""docs/scripts/first_hour.py (the first-hour measurements of docs/benchmarks.md): what it reads from each command's
output, checked against what the commands print (the bench's own formatter, the README's own test command), and its
comparison of two Table I summaries."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from snac_gym.apps.bench import PANDA_GYM, format_env_bench
from snac_gym.apps.real_outputs import late_periods

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def first_hour():
    spec = importlib.util.spec_from_file_location("first_hour", ROOT / "docs" / "scripts" / "first_hour.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["first_hour"] = module  # its dataclass resolves its module by name
    spec.loader.exec_module(module)
    return module


def test_the_bench_ratios_are_read_from_what_the_bench_prints(first_hour):
    rows = {
        "snac_gym/UR10Reach-v0 (pybullet)": {"steps_per_s": 7675.0, "control_dt": 0.008, "round_seconds": [0.8, 0.7]},
        "snac_gym/UR10EllipseTrack-v0 (mujoco)": {"steps_per_s": 9000.0, "control_dt": 0.008},
        PANDA_GYM: {"steps_per_s": 576.0, "control_dt": 0.04, "round_seconds": [10.0, 8.0]},
    }
    for row in rows.values():
        row["real_time_factor"] = row["steps_per_s"] * row["control_dt"]
    ratios = first_hour.bench_ratios("machine: x\n\n" + format_env_bench(rows) + "\n")
    assert set(ratios) == {"snac_gym/UR10Reach-v0 (pybullet)", "snac_gym/UR10EllipseTrack-v0 (mujoco)"}
    reach = ratios["snac_gym/UR10Reach-v0 (pybullet)"]
    assert reach["best"] == pytest.approx(7675 * 0.008 / (576 * 0.04), abs=0.005)
    paired = (0.008 / np.array([0.8, 0.7])) / (0.04 / np.array([10.0, 8.0]))
    assert (reach["low"], reach["high"]) == pytest.approx((paired.min(), paired.max()), abs=0.005)
    assert set(ratios["snac_gym/UR10EllipseTrack-v0 (mujoco)"]) == {"best"}  # no rounds: the best runs' ratio alone


def test_the_own_clock_and_the_test_time_are_the_last_such_lines(first_hour):
    evaluate = (
        "evaluate: 50 samples\nwall time 3.0 s; partial\n...\nwall time 25.1 s; results, summary and plots in x/\n"
    )
    assert first_hour.own_clock(evaluate) == 25.1
    assert first_hour.own_clock("no clock here\n") is None
    pytest_output = (
        "=== slowest 15 durations ===\n12.5s call tests/a.py::test_b\n"
        "==== 2312 passed, 1 skipped, 1 xfailed in 396.80s (0:06:36) ====\n"
    )
    assert first_hour.pytest_runs_seconds(pytest_output) == [396.8]
    assert first_hour.pytest_runs_seconds("== 51 passed, 2 skipped, 2 rerun in 62.20s (0:01:02) ==\n") == [62.2]
    assert first_hour.pytest_runs_seconds("== 3 failed, 5 passed in 1.50s ==\n") == [1.5]
    assert first_hour.pytest_runs_seconds("12.5s call tests/a.py::test_b\n") == []
    both = pytest_output + "...\n== 51 passed, 2 skipped in 62.20s (0:01:02) ==\n"
    assert first_hour.pytest_runs_seconds(both) == [396.8, 62.2]  # the README's test command runs pytest twice


def test_the_main_command_is_the_readmes(first_hour):
    block = first_hour.readme_command((ROOT / "README.md").read_text(encoding="utf-8"), "main-command")
    assert "snac-gym evaluate --out runs/table1 " + " ".join(first_hour.MAIN[1:]) in block
    assert first_hour.SMALL == [*first_hour.MAIN[:1], "--samples", "50", *first_hour.MAIN[1:]]


def test_the_test_runs_are_the_readmes_pytest_steps(first_hour):
    runs = first_hour.readme_pytest_commands((ROOT / "README.md").read_text(encoding="utf-8"))
    assert [words[:2] for words in runs] == [["-m", "pytest"], ["-m", "pytest"]]
    assert runs[0][2:4] == ["-m", "not realtime"] and "tests/realtime" in runs[1]
    with pytest.raises(ValueError, match="no command between <!-- test-command -->"):
        first_hour.readme_pytest_commands("# a README without one\n")


def test_a_summary_cell_that_moved_is_counted_and_the_runs_own_times_are_not(first_hour, tmp_path):
    kept = pd.DataFrame({"controller": ["snac", "optimal"], "reach_cost": [1.5, 1.0], "reach_ratio": [1.5, np.nan],
                         "reach_optimal_solve_time_mean": [np.nan, 0.04], "label": ["SNAC", "optimum"]})  # fmt: skip
    kept.to_csv(tmp_path / "kept.csv", index=False)
    run = tmp_path / "run"
    run.mkdir()
    moved = kept.assign(reach_optimal_solve_time_mean=[np.nan, 0.05])
    moved.to_csv(run / "summary.csv", index=False)
    assert first_hour.changed_cells(run, tmp_path / "kept.csv") == (0, 4)  # NaN equals NaN; the solve time left out
    moved.loc[0, "reach_cost"] = np.nextafter(1.5, 2.0)  # one ulp
    moved.to_csv(run / "summary.csv", index=False, float_format="%.17g")
    assert first_hour.changed_cells(run, tmp_path / "kept.csv") == (1, 4)
    moved.assign(controller=["snac", "lqr"]).to_csv(run / "summary.csv", index=False)
    with pytest.raises(ValueError, match="different controllers"):
        first_hour.changed_cells(run, tmp_path / "kept.csv")


def test_the_late_periods_are_read_from_what_snac_gym_real_prints(first_hour):
    timing = {"late_periods": 4, "periods": 1875, "period_ms_max": 14.84}
    printed = (
        f"  loop period                 8.0 ms\n  late periods                {late_periods(timing)}: counted only\n"
    )
    assert first_hour.late_periods(printed) == (4, 1875, 14.8)
    stalled = late_periods({**timing, "stalled_periods": 2, "period_ms_max": 61.0})
    assert first_hour.late_periods(f"  late periods                {stalled}\n") == (4, 1875, 61.0)
    assert first_hour.late_periods("  no safety stop\n") is None


def test_the_table_puts_each_figure_beside_its_floor_and_its_goal(first_hour):
    def ran(own_clock, cpu=0.0, returncode=0, notes=None):
        return {"own_clock": own_clock, "wall": (own_clock or 20.0) + 1.0, "cpu": cpu, "peak_gb": 1.33,
                "returncode": returncode, "notes": notes or {}}  # fmt: skip

    found = {
        "machine": {"cpus": 2},
        "floor": {"cold_floor": 39.8, "warm_floor": 16.7},
        "runs": {
            "cold": ran(49.2),
            "warm": ran(31.0),
            "small": ran(10.9),
            "tests1": ran(191.1, cpu=339.1),
            "tests2": ran(46.1, cpu=55.2),
            "rehearsal_sim": ran(None, notes={"late_periods": (3, 1875, 13.3)}),
            "rehearsal_dry_run": ran(None, returncode=4),
        },  # fmt: skip
        "bench": {"snac_gym/UR10Reach-v0 (pybullet)": {"best": 2.96}, "snac_gym/UR10Reach-v0 (mujoco)": {"best": 8.0}},
    }
    table = {row[0]: row[1:] for row in first_hour.rows(found)}
    assert table["main command, cold (own clock)"] == ("49.2 s", "39.8 s (ratio 1.24)", "≤ 60: met")
    assert table["main command, warm (own clock)"][2] == "≤ 30: missed"
    assert table["50 samples, cold (wall)"] == ("11.9 s", "–", "≤ 20: met")  # the wall, not the own clock
    assert table["snac_gym/UR10Reach-v0 (pybullet) / panda-gym"] == ("2.96×", "–", "≥ 3: missed")
    assert not any("mujoco" in measure for measure in table)  # the goal is PyBullet's
    assert table["the README's test runs (test time)"] == (
        "237.2 s (191.1 + 46.1)",
        "main suite's CPU / 2 cores: 169.6 s",
        "≤ 150: missed",
    )
    assert table["their largest process"][2] == "≤ 1.5: met"
    assert table["`real --connection sim`, 2 busy"][2] == "exit 0, late periods reported: met"
    assert table["`real --dry-run`, 2 busy"] == (
        "exit 4, no late-periods line",
        "–",
        "exit 0, late periods reported: missed",
    )


def test_a_fresh_clones_runs_are_shown_with_their_install_and_a_failure_misses_its_goal(first_hour):
    def ran(own_clock, wall, returncode=0):
        return {"own_clock": own_clock, "wall": wall, "cpu": 1.0, "peak_gb": 1.0, "returncode": returncode, "notes": {}}

    found = {"machine": {"cpus": 2}, "runs": {"clone_main": ran(50.7, 120.4), "clone_tests": ran(228.8, 362.0)}}
    found["runs"]["clone_tests"]["notes"]["pytest_runs"] = [183.5, 45.3]
    table = {row[0]: row[1:] for row in first_hour.rows(found)}
    assert table["the README's main command, fresh clone (own clock)"] == (
        "50.7 s, exit 0, 2 min 0 s with the install",
        "–",
        "≤ 60: met",
    )
    assert table["the README's test command, fresh clone (test time)"] == (
        "228.8 s (183.5 + 45.3), exit 0, 6 min 2 s with the install",
        "–",
        "≤ 150: missed",
    )
    assert "the README's test runs (test time)" not in table  # the tree's runs only
    found["runs"]["clone_main"] = ran(None, 80.0, returncode=1)  # failed before its evaluate printed a clock
    table = {row[0]: row[1:] for row in first_hour.rows(found)}
    assert table["the README's main command, fresh clone (own clock)"] == (
        "no clock printed, exit 1, 1 min 20 s with the install",
        "–",
        "exit 0 and ≤ 60: missed",
    )


def test_a_readme_block_run_in_bash_is_timed_by_what_its_commands_print(first_hour, tmp_path):
    """The README's blocks run whole in bash: the figure is the evaluate's own clock, or the sum of its pytest runs."""
    printed = "printf 'wall time 12.5 s; results in x/\\n'"
    evaluate = ["bash", "-c", f"{printed} && echo .venv/bin/snac-gym evaluate --out runs/table1"]
    assert first_hour.run("e", evaluate, tmp_path, cwd=tmp_path).own_clock == 12.5
    named = ["bash", "-c", f"{printed} && echo --out runs/evaluate-later"]  # a word of the block, not part of one
    assert first_hour.run("e", named, tmp_path, cwd=tmp_path).own_clock is None
    tests = ["bash", "-c", "printf '== 3 passed in 1.50s ==\\n== 2 passed in 0.25s ==\\n' && echo python -m pytest"]
    both = first_hour.run("t", tests, tmp_path, cwd=tmp_path)
    assert both.own_clock == 1.75 and both.notes["pytest_runs"] == [1.5, 0.25]
    failing = first_hour.run("f", ["bash", "-c", "exit 3"], tmp_path, check=False, cwd=tmp_path)
    assert failing.returncode == 3 and failing.own_clock is None
    with pytest.raises(SystemExit, match="f failed \\(exit 3\\)"):
        first_hour.run("f", ["bash", "-c", "exit 3"], tmp_path, cwd=tmp_path)
