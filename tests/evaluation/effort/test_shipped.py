"""The shipped knobs (snac_gym/data/calibration/default_knobs.json) are the ones the current code matches, and a
run at the default settings uses them, while any other setting still matches its own.

The drift test recomputes what the knobs depend on with the current code, on the same 1000-sample effort set:
the effort reference's passes (the targets) and every knob search. A change to a controller, the rollout, the
samples or the statistic moves a knob or an effort by at least a bit, and the test then fails, naming the
command that writes the file again."""

from __future__ import annotations

import json

import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.controllers import resolve_controllers
from snac_gym.evaluation.effort.matching import EffortMatcher, _ScreenedEffort
from snac_gym.evaluation.effort.search import match_effort
from snac_gym.evaluation.effort.shipped import SHIPPED_ORIGIN, numerics, read_shipped, shipped_file, without_code
from snac_gym.evaluation.execution.executors import open_executor
from snac_gym.evaluation.execution.passes import EvaluationRun
from snac_gym.evaluation.execution.progress import Progress
from snac_gym.evaluation.runner import _calibration_identities, _checked_setting, _effort_set, _sample_set
from snac_gym.evaluation.store import RunStore

MAIN_CONTROLLERS = ("snac", "snac-hjb", "lqr", "rnn", "svf", "dls", "ppo")
STALE = "the shipped knobs are stale: run `python tools/ship_calibration.py` and commit the file"


@pytest.fixture
def cache_on(tmp_path, monkeypatch):
    """The calibration cache on, in an empty folder (the suite turns it off: conftest.py)."""
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("SNAC_GYM_CALIBRATION_CACHE", raising=False)


def _identities(config):
    _, space = _checked_setting(config)
    specs, _ = resolve_controllers(config)
    return _calibration_identities(config, space, specs), specs


#: With the numerics the file was made with (the libraries' versions and numba's target CPU), the knobs must come
#: back bit for bit; with others (another Python's wheels, another CPU), to NUMERICS_RTOL.
NUMERICS_RTOL = 1e-6


def _same_numerics() -> bool:
    made_with = json.loads(shipped_file().read_text())["versions"]
    return all(made_with.get(name) == value for name, value in numerics().items())


def _agree(found: float, shipped: float, exact: bool) -> bool:
    return found == shipped if exact else abs(found - shipped) <= NUMERICS_RTOL * abs(shipped)


def test_the_shipped_knobs_are_the_ones_the_current_code_matches(tmp_path, cache_on):
    config = EvaluationConfig(
        out=tmp_path / "run", controllers=MAIN_CONTROLLERS, workers=1, progress=False, plots=False
    )
    identities, specs = _identities(config)
    shipped = read_shipped(identities)
    assert shipped is not None, f"no shipped knobs for the default settings: {STALE}"
    records, _ = shipped
    searches = json.loads(shipped_file().read_text())["searches"]
    kinematics, space = _checked_setting(config)
    with RunStore(config.out, config.manifest(space, specs), resume=False) as store, open_executor(1) as executor:
        samples, _ = _sample_set(config, kinematics, space, executor, store)
        effort_set = _effort_set(config, kinematics, space, executor, samples)
        assert {task: len(s) for task, s in effort_set.items()} == {"reach": 1000, "track": 1000}
        matcher = EffortMatcher(EvaluationRun(config, store, executor, effort_set, Progress(0, False)))
        reference = next(s for s in specs if s.name == config.effort_reference)
        _, reference_records = matcher._reference_passes(reference)
        exact = _same_numerics()
        for task in config.tasks:
            target = reference_records[(task, reference.name)].effort
            assert _agree(target, records[(task, reference.name)].effort, exact), (
                f"{task}: the effort target moved; {STALE}"
            )
            for spec in specs:
                if spec is reference:
                    continue
                shipped_record = records[(task, spec.name)]
                assert shipped_record.passes == 1 and shipped_record.role == "matched"  # one search decides the knob
                searched = searches[f"{task}/{spec.name}/search1"]
                _check_search(matcher, task, spec, target, searched, shipped_record.knob_value, exact)


def _check_search(matcher, task, spec, target, searched, shipped_knob, exact):
    """The search as the current code runs it, at the cost of about two of its evaluations instead of eleven.

    The search is a deterministic function of the effort at the knobs it asks for, so: it is replayed on the
    efforts the file recorded (asking for any knob the file did not record means the search changed), and the
    effort the current code measures is checked where it decides, at the knob it settles on, with the rollout
    horizon and the screening samples the file recorded. The probe that sets the horizon runs too: its horizon
    must give the recorded number of screening samples. A change to a controller, the rollout, the samples or
    the statistic moves that effort at least by a bit; a change to the search moves the knobs it asks for."""
    recorded = {float(knob): float(effort) for knob, effort in searched["evaluations"]}
    asked: list[float] = []

    def replayed(knob: float) -> float:
        asked.append(knob)
        assert knob in recorded, f"{task}/{spec.name}: the search now asks for the knob {knob!r}; {STALE}"
        return recorded[knob]

    assert _agree(target, searched["target"], exact), f"{task}/{spec.name}: another target; {STALE}"
    replay = match_effort(replayed, searched["target"], searched["start"], matcher.config.effort_tolerance / 4)
    assert replay.value == searched["value"] == shipped_knob and replay.matched, (
        f"{task}/{spec.name}: the search replayed gives {replay.value!r}, the file {shipped_knob!r}; {STALE}"
    )
    samples = matcher.evaluation.samples[task]
    horizon = matcher._probe_horizon(task, spec, float(spec.knob_value), samples)
    if horizon == searched["search_steps"]:  # not lengthened during the search: the count follows from the probe
        assert matcher.screening_count(task, spec, horizon, 1) == searched["screening_samples"], (
            f"{task}/{spec.name}: another number of screening samples; {STALE}"
        )
    screened = _ScreenedEffort(
        matcher, task, spec, samples[: searched["screening_samples"]], searched["search_steps"], 1
    )
    effort = screened.effort_at(searched["value"])
    assert _agree(effort, searched["effort"], exact), (
        f"{task}/{spec.name}: at the shipped knob {shipped_knob!r} the effort is now {effort!r}, the file "
        f"{searched['effort']!r}; {STALE}"
    )


def test_a_run_at_the_defaults_uses_the_shipped_knobs_and_another_setting_matches_its_own(tmp_path, cache_on):
    # Two controllers of the main command on 3 samples: their identities are those of the main command's run
    # (a knob depends on its controller, the effort reference and the effort set, not on the other controllers).
    config = EvaluationConfig(out=tmp_path / "run", samples=3, controllers=("snac", "lqr"), workers=1, progress=False,
                              plots=False, tasks=("reach",))  # fmt: skip
    run_evaluation(config)
    timings = json.loads((tmp_path / "run" / "timings.json").read_text())
    assert "passes at cached knobs" in timings and "effort matching" not in timings
    summary = (tmp_path / "run" / "summary.md").read_text()
    assert "shipped with snac-gym" in summary
    identities, _ = _identities(config)
    knob = read_shipped(identities)[0][("reach", "lqr")].knob_value
    results = json.loads((tmp_path / "run" / "run.json").read_text())
    assert results["seed"] == 0
    import pandas as pd

    rows = pd.read_parquet(tmp_path / "run" / "results.parquet")
    assert set(rows.loc[rows.controller == "lqr", "effort_value"]) == {knob}
    # Another seed is another effort set: nothing shipped fits, the run matches its own knobs.
    other = EvaluationConfig(out=tmp_path / "other", samples=3, seed=5, controllers=("snac", "lqr"), workers=1,
                             progress=False, plots=False, tasks=("reach",), effort_samples=20)  # fmt: skip
    assert read_shipped(_identities(other)[0]) is None
    run_evaluation(other)
    assert "effort matching" in json.loads((tmp_path / "other" / "timings.json").read_text())


def test_a_shipped_entry_for_other_settings_is_not_used(tmp_path, cache_on):
    config = EvaluationConfig(
        out=tmp_path / "run", controllers=MAIN_CONTROLLERS, workers=1, progress=False, plots=False
    )
    identities, _ = _identities(config)
    payload = json.loads(shipped_file().read_text())
    assert read_shipped(identities) is not None
    for change in (
        {"effort_tolerance": 0.05},
        {"steps": 1000},
        {"controller": {"name": "lqr", "kwargs": {"q_scale": 2}}},
    ):
        edited = json.loads(json.dumps(payload))
        entry = next(
            e for e in edited["entries"] if e["record"]["controller"] == "lqr" and e["record"]["task"] == "reach"
        )
        entry["identity"] = {**entry["identity"], **change}
        path = tmp_path / "knobs.json"
        path.write_text(json.dumps(edited))
        assert read_shipped(identities, path) is None, change
    assert without_code({"code": "x", "a": 1}) == {"a": 1}
    assert SHIPPED_ORIGIN.startswith("the knobs shipped")
