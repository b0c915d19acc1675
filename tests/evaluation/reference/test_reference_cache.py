"""The reference's rows cached by sample content (evaluation/reference/cache.py): reused bit for bit,
keyed by everything they depend on, never used for another sample, cost or code."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest
from snac_gym.evaluation.reference import cache as reference_cache
from snac_gym.evaluation.reference.optimum import OptimalJob, run_optimal_job

from snac_gym.control.cost import CostConvention


@pytest.fixture
def job(reference_job) -> OptimalJob:
    return reference_job


@pytest.fixture
def _counting(counted_solves):
    """Start counting the samples solved (not read from the cache) where the test calls it."""

    def start(_monkeypatch=None) -> list[int]:
        counted_solves.clear()
        return counted_solves

    return start


def test_cached_rows_are_the_solved_rows_bit_for_bit(job, _counting, monkeypatch):
    fresh = run_optimal_job(dataclasses.replace(job, cache_dir=None)).metrics
    solved = _counting()
    first = run_optimal_job(job).metrics
    again = run_optimal_job(job).metrics
    assert solved == [3]  # the second run solved nothing
    columns = [c for c in fresh.columns if c != "optimal_solve_time"]  # wall time differs between solves
    pd.testing.assert_frame_equal(first[columns], fresh[columns], check_exact=True)
    pd.testing.assert_frame_equal(again, first, check_exact=True)


def test_a_subset_with_other_ids_reuses_the_rows_of_the_same_samples(job, _counting, monkeypatch):
    first = run_optimal_job(job).metrics
    solved = _counting()
    renumbered = [dataclasses.replace(s, index=s.index + 100) for s in job.samples[1:]]
    subset = dataclasses.replace(job, samples=tuple(renumbered), seeds=(7, 8))
    rows = run_optimal_job(subset).metrics
    assert solved == [] and list(rows["sample"]) == [101, 102]
    pd.testing.assert_frame_equal(rows.drop(columns="sample"),
                                  first.iloc[1:].drop(columns="sample").reset_index(drop=True),
                                  check_exact=True)  # fmt: skip


@pytest.mark.parametrize(
    "change",
    [
        {"convention": CostConvention("hjb", q_scale=4.0)},
        {"steps": 151},
        {"position_limits": False},
        "code",
        "sample",
    ],
    ids=["cost", "horizon", "limits", "code", "sample"],
)
def test_any_other_input_is_solved_anew(job, _counting, monkeypatch, change):
    run_optimal_job(job)
    if change == "code":  # an edited solver, cost or model: another fingerprint
        monkeypatch.setattr(reference_cache, "code_fingerprint", lambda: "edited")
    elif change == "sample":
        moved = dataclasses.replace(job.samples[0], q0=tuple(np.asarray(job.samples[0].q0) + 1e-12))
        job = dataclasses.replace(job, samples=(moved, *job.samples[1:]))
    else:
        job = dataclasses.replace(job, **change)
    solved = _counting()
    run_optimal_job(job)
    assert solved == ([1] if change == "sample" else [3])


def test_an_unreadable_entry_is_solved_again(job, _counting, monkeypatch):
    run_optimal_job(job)
    for path in (reference_cache.Path(job.cache_dir)).glob("*.json"):
        path.write_text("{not json")
        break
    solved = _counting()
    run_optimal_job(job)
    assert solved == [1]


def test_the_key_covers_every_module_the_reference_reaches(tmp_path):
    """The cache key hashes the source of ``code_modules()``, read off the import graph by the project's own
    parser: every module grimp (import-linter's graph, an independent reading) finds upstream of the reference
    must be among them, the solver, the kernels, the robots' tables and the starts' policies included."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    script = (
        "import sys; from pathlib import Path; sys.path.insert(0, sys.argv[1] + '/tools');"
        "from lint_imports import lay_out, ROOT; tree = lay_out(ROOT, Path(sys.argv[2]) / 't');"
        "sys.path.insert(0, str(tree)); import grimp;"
        "g = grimp.build_graph('snac_gym', include_external_packages=False, cache_dir=None);"
        "print('\\n'.join(sorted(g.find_upstream_modules('snac_gym.evaluation.reference.optimum'))))"
    )
    result = subprocess.run(
        [sys.executable, "-c", script, str(root), str(tmp_path)], capture_output=True, text=True, cwd=root
    )
    assert result.returncode == 0, result.stderr
    reached = set(result.stdout.split())
    assert (
        len(reached) >= 40
        and {"snac_gym.model.robots", "snac_gym.model.ur_models", "snac_gym.control.trajopt"} <= reached
    )
    assert reached - set(reference_cache.code_modules()) == set()


def test_the_key_follows_the_shipped_bounds_the_lower_bound_reads(monkeypatch):
    """The shipped bounds on ‖J‖₂ are data, not code: their contents are in the key, so new values are not read back
    from rows computed with the old ones."""
    from snac_gym.control.jacobian_bound import SHIPPED

    assert SHIPPED in reference_cache.DATA_FILES
    reference_cache.code_fingerprint.cache_clear()
    shipped = reference_cache.code_fingerprint()
    monkeypatch.setattr(reference_cache, "DATA_FILES", ("data/calibration/default_knobs.json",))
    reference_cache.code_fingerprint.cache_clear()
    try:
        assert reference_cache.code_fingerprint() != shipped
    finally:
        monkeypatch.undo()
        reference_cache.code_fingerprint.cache_clear()
    assert reference_cache.code_fingerprint() == shipped
