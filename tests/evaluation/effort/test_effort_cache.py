"""The calibration cache (evaluation/effort/cache.py): knobs matched once are reused bit for bit, and never
where anything they depend on changed."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.effort import cache
from snac_gym.evaluation.execution.passes import SIDE_BY_SIDE

SMALL = {"tasks": ("reach", "track"), "horizons": {"reach": 0.4, "track": 0.5}, "controllers": ("snac", "lqr", "dls"),
         "chunk_size": 4, "progress": False, "plots": False}  # fmt: skip


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.SWITCH_ENV, "1")
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache" / "calibration"


def _run(tmp_path, name, **changes):
    config = EvaluationConfig(out=tmp_path / name, **{**SMALL, "samples": 4, "effort_samples": 12, **changes})
    return run_evaluation(config)


def _knobs(results: pd.DataFrame) -> dict[tuple[str, str], float]:
    first = results[results["controller"] != "optimal"].groupby(["task", "controller"])["effort_value"].first()
    return {key: float(value) for key, value in first.items()}


def test_cached_knobs_are_the_recomputed_ones_bit_for_bit_and_so_are_the_rows(cache_dir, tmp_path):
    """A full calibration (12 samples), a smaller run that reads its knobs (4 of the 12, nothing matched; on two
    workers, its passes and optimal reference side by side), and a --recalibrate run that matches anew: the knobs
    and the rows of the 4 samples agree bit for bit."""
    with_optimum = {"controllers": (*SMALL["controllers"], "optimal")}
    full = _run(tmp_path, "full", samples=12, **with_optimum)
    assert len(list(cache_dir.glob("*.json"))) == 6  # 2 tasks × 3 controllers
    cached = _run(tmp_path, "cached", workers=2, **with_optimum)
    summary = (tmp_path / "cached" / "summary.md").read_text()
    assert "The knobs were not matched by this run" in summary
    assert f"the run in {tmp_path / 'full'}" in summary
    timings = json.loads((tmp_path / "cached" / "timings.json").read_text())
    assert "passes at cached knobs" in timings and "effort matching" not in timings
    assert {"optimal", SIDE_BY_SIDE} <= set(timings)
    assert f"the passes and the optimal reference side by side, {timings[SIDE_BY_SIDE]:.1f} s in all" in summary
    fresh = _run(tmp_path, "fresh", recalibrate=True, **with_optimum)
    assert "effort matching" in json.loads((tmp_path / "fresh" / "timings.json").read_text())
    assert "not matched by this run" not in (tmp_path / "fresh" / "summary.md").read_text()
    assert _knobs(cached) == _knobs(fresh) == _knobs(full)
    columns = [c for c in fresh.columns if c != "optimal_solve_time"]
    pd.testing.assert_frame_equal(cached[columns], fresh[columns], check_exact=True)
    first_four = full[full["sample"] < 4].reset_index(drop=True)
    pd.testing.assert_frame_equal(cached[columns], first_four[columns], check_exact=True)


@pytest.mark.parametrize(
    "change",
    [
        {"controller_kwargs": {"dls": {"damping": 0.02}}},  # a parameter of one controller
        {"effort_samples": 16},  # another effort set
        {"effort_tolerance": 0.03},
        {"seed": 1},
    ],
    ids=["controller-parameter", "effort-set", "tolerance", "seed"],
)
def test_a_changed_input_is_not_served_from_the_cache(cache_dir, tmp_path, change):
    _run(tmp_path, "first")
    _run(tmp_path, "changed", **change)
    assert "effort matching" in json.loads((tmp_path / "changed" / "timings.json").read_text())


def test_a_changed_code_version_is_not_served_from_the_cache_nor_a_damaged_entry(cache_dir, tmp_path, monkeypatch):
    _run(tmp_path, "first")
    monkeypatch.setattr(cache, "code_fingerprint", lambda: "another version of the code")
    _run(tmp_path, "new-code")
    assert "effort matching" in json.loads((tmp_path / "new-code" / "timings.json").read_text())
    for entry in cache_dir.glob("*.json"):  # the new code's entries, each cut short
        entry.write_text(entry.read_text()[:40])
    _run(tmp_path, "damaged")
    assert "effort matching" in json.loads((tmp_path / "damaged" / "timings.json").read_text())
    _run(tmp_path, "repaired")  # the damaged run wrote them again
    assert "passes at cached knobs" in json.loads((tmp_path / "repaired" / "timings.json").read_text())


def test_the_code_fingerprint_sees_a_change_to_any_source_file(tmp_path):
    """A copy of the three package folders: one byte added to a controller's source changes the fingerprint,
    and so does a shipped policy file; the fingerprint covers the folders the package runs from."""
    import shutil

    folders = []
    for name, root in cache.package_folders():
        copy = tmp_path / name
        shutil.copytree(root, copy, ignore=shutil.ignore_patterns("__pycache__"))
        folders.append((name, copy))
    assert {name for name, _ in folders} == {"snac_gym", "snac_gym.baselines", "snac_gym.evaluation"}
    before = cache.folders_fingerprint(folders)
    assert cache.folders_fingerprint(folders) == before
    source = tmp_path / "snac_gym.baselines" / "dls.py"
    source.write_text(source.read_text() + " ")
    edited = cache.folders_fingerprint(folders)
    assert edited != before
    report = tmp_path / "snac_gym.evaluation" / "reports" / "writer.py"  # no knob depends on the reports
    report.write_text(report.read_text() + " ")
    assert cache.folders_fingerprint(folders) == edited
    policy = next((tmp_path / "snac_gym" / "ppo" / "models").glob("*.npz"))
    policy.write_bytes(policy.read_bytes()[:-1] + bytes([policy.read_bytes()[-1] ^ 1]))
    assert cache.folders_fingerprint(folders) not in (before, edited)


def test_the_switch_turns_the_cache_off(tmp_path, monkeypatch):
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv(cache.SWITCH_ENV, "off")
    _run(tmp_path, "first")
    assert not (tmp_path / "cache" / "calibration").exists()


def test_a_ppo_row_is_the_same_bits_alone_or_in_any_batch():
    """What lets a run on fewer samples repeat a larger run's rows: a batch's row i is act() of row i alone."""
    import numpy as np

    from snac_gym.ppo.policy import shipped_model_path
    from snac_gym.ppo.policy_file import PolicyFile

    policy = PolicyFile.load(shipped_model_path("reach"))
    inputs = np.random.default_rng(4).normal(size=(300, policy._layers64[0][0].shape[0]))
    batch = policy.network_action(inputs)
    assert np.array_equal(batch[:50], policy.network_action(inputs[:50]))
    assert np.array_equal(batch[17], policy.network_action(inputs[17]))
    assert all(np.array_equal(batch[i], policy.network_action(inputs[i : i + 1])[0]) for i in range(0, 300, 7))
